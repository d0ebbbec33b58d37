"""Robust batch pose-graph optimisation on pyceres (Ceres Solver).

The cost is g2o's: for an edge ``i -> j`` with measurement ``z = (t_z, theta_z)`` and information
``Omega = S^T S``, the residual is ``r = S [R_z^T (R_i^T (p_j - p_i) - t_z); wrap(theta_j -
theta_i - theta_z)]`` and the cost ``1/2 sum rho(|r|^2)`` (``rho`` the identity, or Huber). With
isotropic information this equals, in norm, the paper's world-frame residual ``e_j - e_i - e_ij``
with ``x_ij = d cos(theta_i + heading_rad)`` (likewise y) and ``theta_ij = facing_rad``.

Why it is fast although the residuals are written in Python
------------------------------------------------------------
A Python ``CostFunction`` costs ~10 us per residual-block evaluation, which would dominate the
solve. Here the Python code runs *once per evaluation of the whole problem*, vectorised:

1. Vertices are grouped into *chunks* of consecutive indices; each chunk is one Ceres parameter
   block (a view into one ``(N, 3)`` array). Edges are grouped by the pair of chunks they join;
   each group is one residual block. Far fewer blocks than edges, so far fewer Python calls.
2. A zero-valued *snapshot* residual block depends on every chunk and is evaluated first: it
   copies the current point and computes the residuals and Jacobians of *all* edges in one numpy
   pass. Each edge group then only copies its slice -- after checking that its parameter values are
   exactly the snapshot's (if not, it computes its own edges, so correctness never depends on
   Ceres' evaluation order).
3. Ceres runs with ``dynamic_sparsity``: the chunked Jacobian blocks are mostly zeros, and Ceres
   factorises only the true non-zero structure (the snapshot block's zero row adds nothing).
4. The Huber loss is applied per edge inside the vectorised code as the exact square-root
   reformulation ``r~ = sqrt(rho(s)/s) r`` (``|r~|^2 = rho(|r|^2)``), so Ceres' cost is the robust
   cost, edge by edge, even though many edges share one residual block.
5. Optionally a LAGO linear initialisation (:mod:`cogmap_core.initialization`) puts the start
   close to the optimum, so few Gauss-Newton steps are needed.
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pyceres
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cogmap_core.errors import OptimizationError, ParameterError
from cogmap_core.geometry import wrap_angle
from cogmap_core.initialization import lago_initialization
from cogmap_core.posegraph import PoseGraph

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_IDENTITY = np.eye(3)
AUTO_LAGO_COST_PER_EDGE = 1.0


def _quiet_ceres() -> None:
    """Keep Ceres' glog output off stderr, and SIGTERM a plain termination.

    Ceres reports problems through glog (``E... program_evaluator.h] Accumulated cost = inf``);
    the same text reaches the caller as ``summary.message`` and becomes an OptimizationError, so
    only fatal messages are kept. Importing pyceres installs glog's failure handler, which
    answers SIGTERM with a stack trace that reads as a crash: SIGTERM gets back the handler
    Python had (by default: terminate quietly).
    """
    pyceres.logging.minloglevel = 3  # FATAL only
    try:
        signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGTERM) or signal.SIG_DFL)
    except ValueError:  # imported outside the main thread: cannot touch signals
        pass


_quiet_ceres()
"""With ``initialization="auto"``: LAGO when the initial cost exceeds this many units per edge."""


@dataclass(frozen=True, slots=True)
class OptimizerOptions:
    """Settings of :func:`optimize_pose_graph`.

    Attributes:
        huber_scale: scale ``a`` of the Huber loss ``rho(s) = s`` for ``s <= a^2`` else
            ``2 a sqrt(s) - a^2``, applied to each edge's squared whitened residual; ``None`` for
            plain least squares.
        initialization: ``"none"`` starts from the given poses (warm start); ``"lago"`` from a
            linear LAGO estimate computed from the edges; ``"auto"`` uses LAGO only when the
            given poses are far from consistent with the edges (initial cost above
            ``AUTO_LAGO_COST_PER_EDGE`` per edge, i.e. mean chi^2 well above its noise level).
        max_iterations: Ceres' iteration limit.
        function_tolerance: Ceres stops when the relative cost decrease falls below this.
        chunk_size: vertices per Ceres parameter block.

    """

    huber_scale: float | None = None
    initialization: Literal["none", "lago", "auto"] = "none"
    max_iterations: int = 100
    function_tolerance: float = 1e-6
    chunk_size: int = 32

    def __post_init__(self) -> None:
        """Validate ranges."""
        if self.huber_scale is not None and not self.huber_scale > 0:
            raise ParameterError(f"huber_scale={self.huber_scale} must be > 0 (or None)")
        if self.initialization not in ("none", "lago", "auto"):
            raise ParameterError(
                f"initialization={self.initialization!r} must be 'none', 'lago' or 'auto'"
            )
        if self.max_iterations < 0:
            raise ParameterError(f"max_iterations={self.max_iterations} must be >= 0")
        if not self.function_tolerance > 0:
            raise ParameterError(f"function_tolerance={self.function_tolerance} must be > 0")
        if self.chunk_size < 1:
            raise ParameterError(f"chunk_size={self.chunk_size} must be >= 1")


@dataclass(frozen=True, slots=True)
class OptimizationResult:
    """Outcome of one optimisation.

    Attributes:
        poses: ``(N, 3)`` optimised poses, headings wrapped to ``[-pi, pi)``.
        initial_cost: cost at the given poses (before any initialisation).
        final_cost: cost at the optimised poses.
        iterations: Ceres iterations (successful plus unsuccessful steps, not counting the
            evaluation of the start point).
        wall_s: wall time of the whole optimisation (initialisation, problem set-up, solve).
        termination: Ceres' termination type (``CONVERGENCE``, ``NO_CONVERGENCE``, ...).

    """

    poses: FloatArray
    initial_cost: float
    final_cost: float
    iterations: int
    wall_s: float
    termination: str


# --------------------------------------------------------------------------------------------
# Vectorised residuals and Jacobians
# --------------------------------------------------------------------------------------------


class EdgeModel:
    """Per-edge constants: the measurement and the whitening ``W = S blockdiag(R_z^T, 1)``."""

    def __init__(self, measurements: FloatArray, information: FloatArray) -> None:
        """Precompute whitening from measurements ``(E, 3)`` and information ``(E, 3, 3)``."""
        cz, sz = np.cos(measurements[:, 2]), np.sin(measurements[:, 2])
        rz_t = np.zeros_like(information)
        rz_t[:, 0, 0], rz_t[:, 0, 1], rz_t[:, 1, 0], rz_t[:, 1, 1] = cz, sz, -sz, cz
        rz_t[:, 2, 2] = 1.0
        if (information == _IDENTITY).all():  # the cognitive map's edges: no whitening needed
            self.whitening = rz_t
        else:
            try:
                lower = np.linalg.cholesky(information)  # Omega = L L^T, so S = L^T
            except np.linalg.LinAlgError:
                raise OptimizationError(
                    "an edge information matrix is not positive definite; fix the edge weights"
                ) from None
            self.whitening = lower.transpose(0, 2, 1) @ rz_t
        self.tx = measurements[:, 0].copy()
        self.ty = measurements[:, 1].copy()
        self.ttheta = measurements[:, 2].copy()

    def subset(self, index: IntArray | slice) -> EdgeModel:
        """The model of some of the edges."""
        out = EdgeModel.__new__(EdgeModel)
        out.whitening = self.whitening[index]
        out.tx, out.ty, out.ttheta = self.tx[index], self.ty[index], self.ttheta[index]
        return out


def edge_terms(
    pose_i: FloatArray,
    pose_j: FloatArray,
    model: EdgeModel,
    huber_scale: float | None,
    with_jacobians: bool,
) -> tuple[FloatArray, FloatArray | None]:
    """Whitened (and robustified) residuals ``(E, 3)`` and Jacobians ``(E, 2, 3, 3)``.

    ``jac[:, 0]`` is d r / d pose_i and ``jac[:, 1]`` is d r / d pose_j. With a Huber scale the
    residual is ``sqrt(rho(s)/s) r`` so that its squared norm is ``rho(s)``.
    """
    theta = pose_i[:, 2]
    c, s = np.cos(theta), np.sin(theta)
    dx = pose_j[:, 0] - pose_i[:, 0]
    dy = pose_j[:, 1] - pose_i[:, 1]
    u = c * dx + s * dy
    v = c * dy - s * dx
    err = np.empty((theta.shape[0], 3))
    err[:, 0] = u - model.tx
    err[:, 1] = v - model.ty
    err[:, 2] = wrap_angle(pose_j[:, 2] - theta - model.ttheta)
    w = model.whitening
    res = np.einsum("kab,kb->ka", w, err)
    jac = None
    if with_jacobians:
        d = np.zeros((theta.shape[0], 2, 3, 3))
        d[:, 0, 0, 0], d[:, 0, 0, 1], d[:, 0, 0, 2] = -c, -s, v
        d[:, 0, 1, 0], d[:, 0, 1, 1], d[:, 0, 1, 2] = s, -c, -u
        d[:, 0, 2, 2] = -1.0
        d[:, 1, 0, 0], d[:, 1, 0, 1] = c, s
        d[:, 1, 1, 0], d[:, 1, 1, 1] = -s, c
        d[:, 1, 2, 2] = 1.0
        jac = np.matmul(w[:, None], d)
    if huber_scale is not None:
        res, jac = _apply_huber(res, jac, huber_scale)
    return res, jac


def _apply_huber(
    res: FloatArray, jac: FloatArray | None, scale: float
) -> tuple[FloatArray, FloatArray | None]:
    """Square-root Huber reformulation, exact in value and derivative."""
    sq = np.einsum("ka,ka->k", res, res)
    outer = sq > scale * scale
    if not outer.any():
        return res, jac
    res = res.copy()
    s_out = sq[outer]
    root = np.sqrt(s_out)
    rho = 2.0 * scale * root - scale * scale
    phi = np.sqrt(rho / s_out)
    r_out = res[outer]
    res[outer] = phi[:, None] * r_out
    if jac is not None:
        jac = jac.copy()
        drho = scale / root
        dphi = (drho * s_out - rho) / (2.0 * s_out * s_out * phi)
        j_out = jac[outer]
        r_j = np.einsum("ka,knab->knb", r_out, j_out)
        jac[outer] = (
            phi[:, None, None, None] * j_out
            + 2.0 * dphi[:, None, None, None] * r_out[:, None, :, None] * r_j[:, :, None, :]
        )
    return res, jac


def graph_cost(
    graph: PoseGraph, poses: FloatArray | None = None, huber_scale: float | None = None
) -> float:
    """g2o cost ``1/2 sum rho(|S r|^2)`` of ``graph`` at ``poses`` (default: its own poses)."""
    if graph.num_edges == 0:
        return 0.0
    x = graph.poses if poses is None else poses
    model = EdgeModel(graph.measurements, graph.information)
    res, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, huber_scale, False)
    return 0.5 * float(np.einsum("ka,ka->", res, res))


# --------------------------------------------------------------------------------------------
# Ceres problem: chunked parameter blocks, grouped edges, one vectorised snapshot per evaluation
# --------------------------------------------------------------------------------------------


class _Snapshot:
    """All edge residuals/Jacobians at the point Ceres is currently evaluating."""

    def __init__(
        self,
        poses: FloatArray,
        edge_from: IntArray,
        edge_to: IntArray,
        model: EdgeModel,
        huber_scale: float | None,
        num_chunks: int,
    ) -> None:
        self.poses = poses.copy()
        self.edge_from = edge_from
        self.edge_to = edge_to
        self.model = model
        self.huber_scale = huber_scale
        self.chunk_bytes: list[bytes | None] = [None] * num_chunks
        self.residuals = np.zeros(0)
        self.jacobians = np.zeros(0)
        self.has_jacobians = False
        self.recomputed_groups = 0

    def take(self, chunk_values: list[FloatArray], with_jacobians: bool) -> None:
        self.poses.reshape(-1)[:] = np.concatenate(chunk_values)
        self.chunk_bytes = [values.tobytes() for values in chunk_values]
        x = self.poses
        res, jac = edge_terms(
            x[self.edge_from], x[self.edge_to], self.model, self.huber_scale, with_jacobians
        )
        self.residuals = res.reshape(-1)
        if jac is not None:
            self.jacobians = jac.reshape(-1)
        self.has_jacobians = with_jacobians


class _SnapshotCost(pyceres.CostFunction):
    """A zero residual depending on every chunk: evaluating it takes the snapshot."""

    def __init__(self, snapshot: _Snapshot, chunk_sizes: list[int]) -> None:
        super().__init__()
        self.snapshot = snapshot
        self.set_num_residuals(1)
        self.set_parameter_block_sizes(chunk_sizes)

    def Evaluate(  # noqa: N802 (Ceres' name)
        self, parameters: list[FloatArray], residuals: FloatArray, jacobians: list | None
    ) -> bool:
        self.snapshot.take(parameters, jacobians is not None)
        residuals[0] = 0.0
        if jacobians is not None:
            for block in jacobians:
                if block is not None:
                    block.fill(0.0)
        return True


@dataclass(frozen=True, slots=True)
class _GroupPlan:
    """Where one edge group's Jacobian entries come from and go to.

    ``source[k]`` indexes the snapshot's flat Jacobian array ``(E, 2, 3, 3)``; ``target[k]`` the
    flat Jacobian buffer Ceres gives for the group's ``k``-th parameter block (row-major
    ``(3 edges, 3 n_block)``). ``local_from``/``local_to`` index vertices in the concatenation of
    the group's chunks (for the fallback evaluation).
    """

    first_edge: int
    end_edge: int
    chunks: list[int]
    source: list[IntArray]
    target: list[IntArray]
    local_from: IntArray
    local_to: IntArray


def _plan_groups(
    edge_from: IntArray,
    edge_to: IntArray,
    chunk_of: IntArray,
    chunk_start: IntArray,
    chunk_len: IntArray,
) -> list[_GroupPlan]:
    """Split edges (already sorted by chunk pair) into groups and plan their Jacobian scatter."""
    e = edge_from.shape[0]
    ends = np.stack([edge_from, edge_to], axis=1)  # (E, 2)
    chunk = chunk_of[ends]
    lo = chunk.min(axis=1)
    hi = chunk.max(axis=1)
    key = lo * (int(chunk_of.max()) + 1) + hi
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    group_of = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, e]))
    q = np.arange(e) - starts[group_of]  # edge index within its group
    block = (chunk != lo[:, None]).astype(np.int64)  # 0: first chunk of the group, 1: second
    within = ends - chunk_start[chunk]  # vertex index inside its chunk
    n_block = chunk_len[chunk]
    local = within + block * chunk_len[lo][:, None]
    a = np.arange(3)[None, None, :, None]
    b = np.arange(3)[None, None, None, :]
    target = (3 * q[:, None, None, None] + a) * (3 * n_block[:, :, None, None]) + (
        3 * within[:, :, None, None] + b
    )
    source = np.arange(e * 18, dtype=np.int64).reshape(e, 2, 3, 3)
    slot = np.broadcast_to((group_of[:, None] * 2 + block)[:, :, None, None], target.shape)
    order = np.argsort(slot.reshape(-1), kind="stable")
    slot_sorted = slot.reshape(-1)[order]
    target_sorted = target.reshape(-1)[order]
    source_sorted = source.reshape(-1)[order]
    bounds = np.searchsorted(slot_sorted, np.arange(2 * starts.size + 1))
    plans = []
    for g, g0 in enumerate(starts.tolist()):
        g1 = int(starts[g + 1]) if g + 1 < starts.size else e
        chunks = [int(lo[g0])] if lo[g0] == hi[g0] else [int(lo[g0]), int(hi[g0])]
        src, tgt = [], []
        for k in range(len(chunks)):
            s0, s1 = int(bounds[2 * g + k]), int(bounds[2 * g + k + 1])
            src.append(source_sorted[s0:s1])
            tgt.append(target_sorted[s0:s1])
        plans.append(
            _GroupPlan(g0, g1, chunks, src, tgt, local[g0:g1, 0].copy(), local[g0:g1, 1].copy())
        )
    return plans


class _EdgeGroupCost(pyceres.CostFunction):
    """The edges joining one chunk to itself or to one other chunk (contiguous in edge order)."""

    def __init__(self, snapshot: _Snapshot, plan: _GroupPlan, chunk_len: IntArray) -> None:
        super().__init__()
        self.snapshot = snapshot
        self.plan = plan
        self.set_num_residuals(3 * (plan.end_edge - plan.first_edge))
        self.set_parameter_block_sizes([3 * int(chunk_len[c]) for c in plan.chunks])
        self.res_slice = slice(plan.first_edge * 3, plan.end_edge * 3)
        self.local_source = [src - plan.first_edge * 18 for src in plan.source]

    def _is_fresh(self, parameters: list[FloatArray], with_jacobians: bool) -> bool:
        snap = self.snapshot
        if with_jacobians and not snap.has_jacobians:
            return False
        for chunk, values in zip(self.plan.chunks, parameters, strict=True):
            if snap.chunk_bytes[chunk] != values.tobytes():
                return False
        return True

    def Evaluate(  # noqa: N802 (Ceres' name)
        self, parameters: list[FloatArray], residuals: FloatArray, jacobians: list | None
    ) -> bool:
        snap = self.snapshot
        plan = self.plan
        with_jacobians = jacobians is not None
        if self._is_fresh(parameters, with_jacobians):
            residuals[:] = snap.residuals[self.res_slice]
            if jacobians is not None:
                jac = snap.jacobians
                for block, source, target in zip(jacobians, plan.source, plan.target, strict=True):
                    if block is not None:
                        block.fill(0.0)
                        block[target] = jac[source]
            return True
        # Ceres evaluated this block at another point than the snapshot: compute it on its own.
        snap.recomputed_groups += 1
        x = np.concatenate(parameters).reshape(-1, 3)
        model = snap.model.subset(slice(plan.first_edge, plan.end_edge))
        res, jac = edge_terms(
            x[plan.local_from], x[plan.local_to], model, snap.huber_scale, with_jacobians
        )
        residuals[:] = res.reshape(-1)
        if jacobians is not None and jac is not None:
            flat = jac.reshape(-1)
            for block, source, target in zip(
                jacobians, self.local_source, plan.target, strict=True
            ):
                if block is not None:
                    block.fill(0.0)
                    block[target] = flat[source]
        return True


def _gauge_fixed(graph: PoseGraph) -> NDArray[np.bool_]:
    """Fixed vertices: the graph's own, plus the first vertex of every component without one."""
    fixed = graph.fixed.copy()
    n = graph.num_vertices
    adjacency = coo_matrix(
        (np.ones(graph.num_edges), (graph.edge_from, graph.edge_to)), shape=(n, n)
    )
    count, labels = connected_components(adjacency, directed=False)
    has_fixed = np.zeros(count, dtype=bool)
    has_fixed[labels[fixed]] = True
    _, first = np.unique(labels, return_index=True)
    for component, vertex in enumerate(first.tolist()):
        if not has_fixed[component]:
            fixed[vertex] = True
    return fixed


def _chunk_bounds(n: int, fixed: NDArray[np.bool_], chunk_size: int) -> list[tuple[int, int]]:
    """Contiguous index ranges of at most ``chunk_size``; every fixed vertex alone in its range."""
    bounds: list[tuple[int, int]] = []
    start = 0
    for f in np.flatnonzero(fixed).tolist() + [n]:
        for a in range(start, f, chunk_size):
            bounds.append((a, min(a + chunk_size, f)))
        if f < n:
            bounds.append((f, f + 1))
        start = f + 1
    return bounds


def optimize_pose_graph(
    graph: PoseGraph, options: OptimizerOptions | None = None
) -> OptimizationResult:
    """Optimise ``graph`` with Ceres (sparse normal Cholesky, dynamic sparsity).

    The graph's fixed vertices stay put; a connected component without a fixed vertex has its
    first vertex fixed (the gauge). Headings are unconstrained during the solve (residual angles
    are wrapped) and wrapped to ``[-pi, pi)`` in the result.

    Raises:
        OptimizationError: non-finite poses or measurements, or Ceres failed.

    """
    options = options or OptimizerOptions()
    started = time.perf_counter()
    if not (np.isfinite(graph.poses).all() and np.isfinite(graph.measurements).all()):
        raise OptimizationError("the pose graph has NaN or infinite poses or measurements")
    initial_cost = graph_cost(graph, huber_scale=options.huber_scale)
    n, e = graph.num_vertices, graph.num_edges
    fixed = _gauge_fixed(graph) if n else graph.fixed
    if e == 0 or fixed.all() or options.max_iterations == 0:
        poses = graph.poses.copy()
        poses[:, 2] = wrap_angle(poses[:, 2])
        return OptimizationResult(
            poses, initial_cost, initial_cost, 0, time.perf_counter() - started, "NO_PROBLEM"
        )

    work = graph.copy()
    work.fixed = fixed
    use_lago = options.initialization == "lago" or (
        options.initialization == "auto" and initial_cost > AUTO_LAGO_COST_PER_EDGE * e
    )
    if use_lago:
        with np.errstate(over="ignore", invalid="ignore"):
            work.poses = lago_initialization(work)
        if not np.isfinite(work.poses).all():
            raise OptimizationError(
                "the LAGO initialisation overflowed: the graph's values are too large; rescale "
                "the graph, or start from its own poses (initialization 'none')"
            )
    poses = np.ascontiguousarray(work.poses, dtype=np.float64)

    bounds = _chunk_bounds(n, fixed, options.chunk_size)
    chunk_of = np.empty(n, dtype=np.int64)
    for c, (a, b) in enumerate(bounds):
        chunk_of[a:b] = c
    ci, cj = chunk_of[work.edge_from], chunk_of[work.edge_to]
    lo, hi = np.minimum(ci, cj), np.maximum(ci, cj)
    order = np.argsort(lo * len(bounds) + hi, kind="stable")
    edge_from, edge_to = work.edge_from[order], work.edge_to[order]
    model = EdgeModel(work.measurements[order], work.information[order])
    blocks = [poses[a:b].reshape(-1) for a, b in bounds]
    snapshot = _Snapshot(poses, edge_from, edge_to, model, options.huber_scale, len(bounds))

    problem = pyceres.Problem()
    problem.add_residual_block(_SnapshotCost(snapshot, [blk.size for blk in blocks]), None, blocks)
    chunk_start = np.array([a for a, _ in bounds], dtype=np.int64)
    chunk_len = np.array([b - a for a, b in bounds], dtype=np.int64)
    for plan in _plan_groups(edge_from, edge_to, chunk_of, chunk_start, chunk_len):
        problem.add_residual_block(
            _EdgeGroupCost(snapshot, plan, chunk_len), None, [blocks[c] for c in plan.chunks]
        )
    for c, (a, b) in enumerate(bounds):
        if b - a == 1 and fixed[a]:
            problem.set_parameter_block_constant(blocks[c])

    solver_options = pyceres.SolverOptions()
    solver_options.linear_solver_type = pyceres.LinearSolverType.SPARSE_NORMAL_CHOLESKY
    solver_options.dynamic_sparsity = True
    solver_options.num_threads = 1  # the Python callbacks hold the GIL anyway
    solver_options.max_num_iterations = options.max_iterations
    solver_options.function_tolerance = options.function_tolerance
    solver_options.initial_trust_region_radius = 1e8
    solver_options.logging_type = pyceres.LoggingType.SILENT
    summary = pyceres.SolverSummary()
    pyceres.solve(solver_options, problem, summary)
    termination = str(summary.termination_type).rsplit(".", 1)[-1]
    if termination == "FAILURE" or not np.isfinite(poses).all():
        raise OptimizationError(f"Ceres failed: {' '.join(str(summary.message).split())}")
    poses[:, 2] = wrap_angle(poses[:, 2])
    # Ceres' cost is the robust cost itself (the snapshot residual is zero)
    final_cost = float(summary.final_cost)
    if not use_lago:
        initial_cost = float(summary.initial_cost)
    return OptimizationResult(
        poses=poses,
        initial_cost=initial_cost,
        final_cost=final_cost,
        # Ceres counts the evaluation at the start point as a successful step: leave it out.
        iterations=int(summary.num_successful_steps + summary.num_unsuccessful_steps) - 1,
        wall_s=time.perf_counter() - started,
        termination=termination,
    )
