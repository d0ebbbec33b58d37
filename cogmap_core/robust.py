"""Robust loop-closure models: how much the batch optimisation believes each loop closure.

The paper optimises every edge under a Huber loss and names false loop closures its open problem.
Huber bounds a false link's pull but never removes it: a hundred false links on the Manhattan
graph still drag it 30 m off (``benchmarks/robust.py``). The field's answers give the
loop-closure term a *redescending* kernel -- a residual far beyond the link's precision costs
about a constant, so the link stops pulling -- and the odometry stays Gaussian.

A kernel ``rho(s)`` acts on an edge's squared whitened residual ``s = |S r|^2`` (its chi^2, in
units of the edge's own standard deviation); ``scale`` ``c`` is where it starts to discount:

- ``huber``: ``s`` up to ``c^2``, then ``2 c sqrt(s) - c^2`` (convex; the paper's loss);
- ``cauchy``: ``c^2 log(1 + s / c^2)``;
- ``geman_mcclure``: ``c^2 s / (c^2 + s)``. It is also the closed form of switchable
  constraints (Suenderhauf & Protzel) with switch prior ``c^2``: minimising
  ``w^2 s + c^2 (1 - w)^2`` over the switch ``w`` gives ``w = c^2 / (c^2 + s)`` and this cost;
- ``dcs``: dynamic covariance scaling (Agarwal et al. 2013) as g2o implements it: the residual
  is scaled by ``min(1, 2 c^2 / (c^2 + s))`` (``Phi = c^2``);
- ``max_mixture`` (Olson & Agarwal 2013): per link, the likelier of an inlier Gaussian and a
  null hypothesis :data:`MAX_MIXTURE_WIDTH` times wider holding :data:`MAX_MIXTURE_NULL_WEIGHT`
  of the mass; its cost is ``min(s, s / k^2 + C)`` (``rho(0) = 0``); ``scale`` is unused.

**How it is solved: iteratively reweighted least squares** (IRLS), as GTSAM and g2o linearise
robust kernels: each loop closure gets the weight ``w = rho'(s)`` (DCS: its squared scaling;
max-mixture: that of its likelier component) at the current estimate, a few Gauss-Newton /
Levenberg-Marquardt iterations of the weighted least-squares problem follow, and the weights are
recomputed, until the robust cost changes by less than :data:`IRLS_TOLERANCE` (a map's
optimisations: :data:`MAP_IRLS_TOLERANCE`). For concave
``rho`` (all but DCS and the max-mixture) each reweighting is a majorise-minimise step, so the
robust cost never rises. A weight below :data:`DROP_WEIGHT` is set to exactly zero: the link
then leaves the linear system of that iteration (its chi^2 is ``1 / DROP_WEIGHT`` times the
scale's and its pull ``w |r|`` is negligible), so rejected false links cost the sparse solver
nothing -- with a thousand random false links on Manhattan that is the difference between 5 s
and 1.5 s. (Solving the kernel directly, with its exact curvature in Ceres, was measured
first: 100 iterations without converging, 12.7 m off with a thousand false links.)

**A drifted start.** A redescending kernel judges a link by its residual at the current
estimate, so the first return after a long exploration -- metres off because the odometry
drifted, not because the link is false -- would be rejected and the map never corrected (on
generated logs with 36-43 m of dead-reckoning drift, the maps built from the *true* links alone
stayed 35-41 m off with Geman-McClure; Huber's convexity kept them at 2-3 m). So when IRLS
rejects some of the links added since the last optimisation, the other hypothesis is solved
too: from the same start, those links under the convex Huber kernel at the same scale (the
other loop closures keep their weights at the start), then IRLS as before; the solution of
lower robust cost -- the more probable under the model -- is kept
(:func:`~cogmap_core.optimizer.optimize_pose_graph`'s ``new_loops``). A true cluster of links
then costs less accepted than rejected; a false one costs more accepted, because the odometry
must bend to satisfy it. Measured first and dropped: graduating new links from the drift the
odometry could explain along the graph (as the relocalisation test does), and choosing the
hypothesis with more inlier links (both in ``docs/maps.md``). A map's clusters of links are also
judged against each other, so that one cluster of look-alike links cannot overrule several
earlier ones (:mod:`cogmap_core.cluster_consistency`).

**Graduated non-convexity** (Yang, Antonante, Tzoumas & Carlone, RA-L 2020), with the
Geman-McClure kernel, for any pose graph (``cogmap optimize --robust --gnc``): GNC-GM's
surrogate ``rho_mu`` is Geman-McClure at scale ``sqrt(mu) c``, so the first reweightings use a
scale at which every loop closure of the start point is in the near-quadratic zone
(``mu_0 = 2 s_max / c^2``: least squares, convex) and each next one divides it by
:data:`GNC_SHRINK` until it reaches ``c``; IRLS then continues at ``c``. From least squares
with many false links the start is already wrong (``benchmarks/robust.py``).

A link whose final chi^2 is past its kernel's scale is **rejected** (for Geman-McClure its
weight is then below a quarter, for the max-mixture the null hypothesis is the likelier).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import ParameterError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

KERNELS = ("huber", "cauchy", "geman_mcclure", "dcs", "max_mixture")
"""The robust kernels a loop closure may be judged with."""
DEFAULT_LOOP_KERNEL = "dcs"
"""The kernel of ``cogmap optimize --robust`` (the maps: ``MapParams.loop_model``). On M3500 and
intel with up to 1,256 random false loop closures DCS ended within 0.006 m of the outlier-free
optimum where Geman-McClure once ended 2.9 m off (M3500 + 1,000), and without outliers DCS keeps
the least-squares cost exactly (Geman-McClure discounts true closures: -2.7 % on M3500); it
fails at 50 % false closures on M3500 (8.0 m; Geman-McClure 0.010 m) (``benchmarks/robust.py``)."""

MAX_MIXTURE_WIDTH = 10.0
"""The null hypothesis of the max-mixture is this many times the link's standard deviation."""
MAX_MIXTURE_NULL_WEIGHT = 0.1
"""... and holds this share of the mixture's weight."""
GNC_SHRINK = 2.0
"""Each graduated reweighting divides the kernel's scale by this."""


IRLS_TOLERANCE = 1e-5
"""Reweighting stops when the robust cost changes by less than this fraction (one solve)."""
MAP_IRLS_TOLERANCE = 1e-3
"""... in a map's optimisations, which each next cluster continues from
(``LoopClosureModel.tolerance``). Against 1e-5: the four built-in layouts' maps identical (V, ATE
to 0.1 mm, fidelity), four generated logs' within 0.02 m, Lecture Hall's within 1 mm and 0.001 of
fidelity, its optimisations 1.7x faster."""
IRLS_ITERATIONS = 5
"""Ceres iterations between two reweightings."""
IRLS_MAX_REWEIGHTINGS = 50
"""Reweighting stops after this many rounds whatever the change."""
DROP_WEIGHT = 1e-6
"""A loop closure weighing less than this takes no part in the next iterations' linear system."""


@dataclass(frozen=True, slots=True)
class Kernel:
    """A robust kernel ``rho(s)`` of the squared whitened residual ``s`` (module doc)."""

    name: str
    scale: float = 1.0

    def __post_init__(self) -> None:
        """Reject unknown kernels and scales that are not positive and finite."""
        if self.name not in KERNELS:
            raise ParameterError(f"robust kernel {self.name!r} is unknown; known: {KERNELS}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ParameterError(f"robust kernel scale {self.scale!r} must be > 0 and finite")

    def evaluate(self, s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``rho(s)`` and the IRLS weight (``rho'(s)`` but for ``dcs`` and ``max_mixture``)."""
        c2 = self.scale * self.scale
        if self.name == "huber":
            outer = s > c2
            root = np.sqrt(np.where(outer, s, 1.0))
            rho = np.where(outer, 2.0 * self.scale * root - c2, s)
            return rho, np.where(outer, self.scale / root, 1.0)
        if self.name == "cauchy":
            return c2 * np.log1p(s / c2), c2 / (c2 + s)
        if self.name == "geman_mcclure":
            denominator = c2 + s
            return c2 * s / denominator, (c2 / denominator) ** 2
        if self.name == "dcs":
            weight = np.minimum(1.0, 2.0 * c2 / (c2 + s)) ** 2
            return weight * s, weight
        k2 = MAX_MIXTURE_WIDTH**2
        offset = 2.0 * (3.0 * math.log(MAX_MIXTURE_WIDTH) - math.log(MAX_MIXTURE_NULL_WEIGHT))
        offset += 2.0 * math.log(1.0 - MAX_MIXTURE_NULL_WEIGHT)
        null = s / k2 + offset
        inlier = s <= null
        return np.where(inlier, s, null), np.where(inlier, 1.0, 1.0 / k2)

    def weight(self, s: FloatArray) -> FloatArray:
        """The weight iteratively reweighted least squares gives a residual of chi^2 ``s``."""
        return self.evaluate(s)[1]

    def rejects(self, s: FloatArray) -> BoolArray:
        """Whether residuals of chi^2 ``s`` are past the kernel's scale (rejected links)."""
        if self.name == "max_mixture":
            return self.weight(s) < 1.0
        return s > self.scale * self.scale


@dataclass(frozen=True, slots=True, eq=False)
class Weights:
    """Fixed per-edge weights ``w`` (one per edge of the graph): the residual ``sqrt(w) r``."""

    values: FloatArray


def apply_kernel(
    res: FloatArray,
    jac: FloatArray | None,
    kernel: Kernel | Weights,
    rows: BoolArray | None,
) -> tuple[FloatArray, FloatArray | None]:
    """Robustify the residuals (and Jacobians) of the edges ``rows`` (None: all).

    With :class:`Weights` the residual is ``sqrt(w) r`` and its Jacobian ``sqrt(w) J`` (one
    least-squares problem of IRLS). With a :class:`Kernel`, the square-root reformulation
    ``r~ = phi r``, ``phi = sqrt(rho(s) / s)``, has ``|r~|^2 = rho(s)``, so Ceres' cost is the
    robust cost edge by edge, and the Jacobian ``phi J + 2 phi'(s) r (r^T J)`` is exact where
    the kernel's weight is ``rho'`` (the paper's Huber loss is solved this way). Residuals with
    ``s`` below ``1e-18`` are left as they are (every kernel here has ``rho'(0) = 1``).
    """
    if isinstance(kernel, Weights):
        root = np.sqrt(kernel.values if rows is None else np.where(rows, kernel.values, 1.0))
        res = root[:, None] * res
        if jac is not None:
            jac = root[:, None, None, None] * jac
        return res, jac
    sq = np.einsum("ka,ka->k", res, res)
    pick = sq > 1e-18
    if rows is not None:
        pick &= rows
    if kernel.name == "huber":
        pick &= sq > kernel.scale * kernel.scale  # identity inside: nothing to change
    if not pick.any():
        return res, jac
    res = res.copy()
    s = sq[pick]
    rho, drho = kernel.evaluate(s)
    phi = np.sqrt(rho / s)
    r_sel = res[pick]
    res[pick] = phi[:, None] * r_sel
    if jac is not None:
        jac = jac.copy()
        dphi = (drho * s - rho) / (2.0 * s * s * phi)
        j_sel = jac[pick]
        r_j = np.einsum("ka,knab->knb", r_sel, j_sel)
        jac[pick] = (
            phi[:, None, None, None] * j_sel
            + 2.0 * dphi[:, None, None, None] * r_sel[:, None, :, None] * r_j[:, :, None, :]
        )
    return res, jac


@dataclass(frozen=True, slots=True)
class LoopClosureModel:
    """How the batch optimisation treats loop-closure edges (the other edges stay Gaussian).

    Attributes:
        kernel: one of :data:`KERNELS`.
        scale: the kernel's scale in standard deviations of the link (a chi of 1 is a
            residual of one link sigma).
        graduated: reach the kernel by graduated non-convexity from least squares, every loop
            closure starting at GNC-GM's ``mu_0`` (only with ``geman_mcclure``).
        tolerance: reweighting stops when the robust cost changes by less than this fraction.

    """

    kernel: str = "geman_mcclure"
    scale: float = 1.0
    graduated: bool = False
    tolerance: float = IRLS_TOLERANCE

    def __post_init__(self) -> None:
        """Validate (the kernel and scale through :class:`Kernel`)."""
        Kernel(self.kernel, self.scale)
        if self.graduated and self.kernel != "geman_mcclure":
            raise ParameterError(
                f"graduated non-convexity needs the geman_mcclure kernel, not {self.kernel!r}"
            )
        if not 0 < self.tolerance < 1:
            raise ParameterError(f"IRLS tolerance {self.tolerance} must be in (0, 1)")

    @property
    def final_kernel(self) -> Kernel:
        """The kernel the optimisation minimises in the end."""
        return Kernel(self.kernel, self.scale)


class Reweighting:
    """The IRLS schedule of one optimisation: the next weights, or None when it is done.

    Args:
        model: the loop model.
        loops: ``(E,)`` which edges are loop closures.

    A graduated model starts every loop closure at GNC-GM's ``sqrt(2 s_max)`` and halves the
    scale each round down to the model's; IRLS then goes on at the model's kernel.

    """

    def __init__(self, model: LoopClosureModel, loops: BoolArray) -> None:
        """Start before the first reweighting."""
        self.model = model
        self.loops = loops
        self.rounds = 0
        self.converged = False
        self._scales: FloatArray | None = None
        self._cost = math.inf

    def next(self, chi2: FloatArray, cost: float) -> FloatArray | None:
        """Weights of every edge (1 off the loop closures) for the next iterations, or None.

        Args:
            chi2: ``(E,)`` squared whitened residuals at the current estimate.
            cost: the robust cost (final kernel) at the current estimate.

        """
        if not self.loops.any():
            self.converged = True
            return None
        final = self.model.final_kernel
        if self._scales is None:
            self._scales = np.zeros(chi2.shape[0])
            if self.model.graduated:
                self._scales[self.loops] = math.sqrt(2.0 * float(chi2[self.loops].max()))
        if self.rounds >= IRLS_MAX_REWEIGHTINGS:
            return None
        weights = np.where(self.loops, final.weight(chi2), 1.0)
        graduating = self._scales > final.scale
        if graduating.any():
            scale2 = self._scales[graduating] ** 2
            weights[graduating] = (scale2 / (scale2 + chi2[graduating])) ** 2
            self._scales = np.where(graduating, self._scales / GNC_SHRINK, 0.0)
        else:
            if abs(self._cost - cost) <= self.model.tolerance * cost:
                self.converged = True
                return None
            self._cost = cost
        self.rounds += 1
        return drop_small(weights)


def drop_small(weights: FloatArray) -> FloatArray:
    """Weights below :data:`DROP_WEIGHT` set to exactly zero (module doc)."""
    weights[weights < DROP_WEIGHT] = 0.0
    return weights


LOOP_MODELS: tuple[LoopClosureModel | None, ...] = (
    None,
    LoopClosureModel("cauchy"),
    LoopClosureModel("geman_mcclure"),
    LoopClosureModel("dcs"),
    LoopClosureModel("max_mixture"),
    LoopClosureModel("geman_mcclure", graduated=True),
)
"""The map's ``loop_model`` codes: 0 the paper's Huber on every edge (no loop model), then
Cauchy, Geman-McClure, DCS, max-mixture and graduated Geman-McClure (at scale 1)."""


def loop_closure_model(
    code: int, scale: float, tolerance: float = IRLS_TOLERANCE
) -> LoopClosureModel | None:
    """The loop model of a ``loop_model`` code at ``scale`` (None: the paper's Huber)."""
    model = LOOP_MODELS[code]
    if model is None:
        return None
    return LoopClosureModel(model.kernel, scale, model.graduated, tolerance)
