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
   The indices are those of an order in which the edges join near vertices (reverse
   Cuthill-McKee): in the graph's own order every loop closure joins chunks laps apart, a
   residual block of its own (a standard map of the default dataset: 145 blocks instead of 349;
   its rebuild's solves 1.1-1.2x faster, the same poses to 1e-13).
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

import math
import signal
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pyceres
from numpy.typing import NDArray
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, reverse_cuthill_mckee

from cogmap_core.ceres_blocks import EdgeGroupCost, Snapshot, SnapshotCost, plan_groups
from cogmap_core.cluster_consistency import overrules_a_merge, overrules_several
from cogmap_core.edge_residuals import (
    EdgeLosses,
    EdgeModel,
    chi2,
    edge_losses,
    edge_terms,
    graph_cost,
    subset_loss,
)
from cogmap_core.errors import OptimizationError, ParameterError
from cogmap_core.geometry import wrap_angle
from cogmap_core.initialization import lago_initialization
from cogmap_core.posegraph import PoseGraph
from cogmap_core.robust import (
    IRLS_ITERATIONS,
    Kernel,
    LoopClosureModel,
    Reweighting,
    Weights,
    apply_kernel,
    drop_small,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

AUTO_LAGO_COST_PER_EDGE = 1.0
"""With ``initialization="auto"``: LAGO when the initial cost exceeds this many units per edge."""


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
        max_iterations: Ceres' iteration limit (per stage of a graduated solve).
        function_tolerance: Ceres stops when the relative cost decrease falls below this.
        chunk_size: vertices per Ceres parameter block.
        loop_model: a robust model for the loop-closure edges (:mod:`cogmap_core.robust`;
            :meth:`PoseGraph.loop_closures` says which edges); they then take its kernel
            instead of the Huber loss, which stays on the other edges. None: every edge alike.

    """

    huber_scale: float | None = None
    initialization: Literal["none", "lago", "auto"] = "none"
    max_iterations: int = 100
    function_tolerance: float = 1e-6
    chunk_size: int = 32
    loop_model: LoopClosureModel | None = None

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
        rejected: ``(E,)`` loop closures the loop model rejected (their final chi^2 is past
            its kernel's scale), in the graph's edge order; all False without a loop model.
        reweightings: rounds of iteratively reweighted least squares the loop model ran
            (:mod:`cogmap_core.robust`; 0 without one).

    """

    poses: FloatArray
    initial_cost: float
    final_cost: float
    iterations: int
    wall_s: float
    termination: str
    rejected: NDArray[np.bool_] | None = None
    reweightings: int = 0

    @property
    def num_rejected(self) -> int:
        """How many loop closures the loop model rejected."""
        return 0 if self.rejected is None else int(np.count_nonzero(self.rejected))


class _EdgeResiduals:
    """The whitened residuals (no kernel) of a graph's edges, in its edge order."""

    def __init__(self, graph: PoseGraph) -> None:
        self.edge_from, self.edge_to = graph.edge_from, graph.edge_to
        self.model = EdgeModel(graph.measurements, graph.information)

    def at(self, poses: FloatArray) -> FloatArray:
        """``(E, 3)`` residuals at ``poses`` (graph order)."""
        res, _ = edge_terms(poses[self.edge_from], poses[self.edge_to], self.model, None, False)
        return res


def _chi2_of(res: FloatArray) -> FloatArray:
    """``(E,)`` squared norms of residuals (as :func:`chi2`)."""
    return np.einsum("ka,ka->k", res, res)


def _cost_of(res: FloatArray, losses: EdgeLosses) -> float:
    """The cost ``1/2 sum rho(|r|^2)`` of residuals without kernel (as :func:`graph_cost`)."""
    for rows, kernel in losses:
        res, _ = apply_kernel(res, None, kernel, rows)
    return 0.5 * float(np.einsum("ka,ka->", res, res))


def _adjacency(graph: PoseGraph) -> csr_matrix:
    """The vertices' symmetric adjacency matrix (an edge's weight: how many edges join them)."""
    n = graph.num_vertices
    one_way = coo_matrix(
        (np.ones(graph.num_edges), (graph.edge_from, graph.edge_to)), shape=(n, n)
    ).tocsr()
    return (one_way + one_way.T).tocsr()


def _vertex_order(adjacency: csr_matrix) -> IntArray:
    """An order of the vertices in which the edges join near vertices (reverse Cuthill-McKee).

    In index order a loop closure joins vertices laps apart, so each one is an edge between
    two chunks of its own -- a residual block, hence a Python call per evaluation. In this
    order the bandwidth of the graph is small (26 vertices on the default dataset's standard
    map of 2287 vertices, against 2084), and nearly every edge joins a chunk to itself or to
    the next one: 145 residual blocks instead of 349 there.
    """
    return reverse_cuthill_mckee(adjacency, symmetric_mode=True).astype(np.int64)


def _gauge_fixed(graph: PoseGraph, adjacency: csr_matrix) -> NDArray[np.bool_]:
    """Fixed vertices: the graph's own, plus the first vertex of every component without one."""
    fixed = graph.fixed.copy()
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


def _final_losses(graph: PoseGraph, options: OptimizerOptions) -> EdgeLosses:
    """The kernels of the cost the optimisation minimises, per edge in graph order."""
    if options.loop_model is None:
        return edge_losses(options.huber_scale)
    loops = graph.loop_closures()
    final: list[tuple[NDArray[np.bool_] | None, Kernel]] = [
        (loops, options.loop_model.final_kernel)
    ]
    if options.huber_scale is not None:
        final.append((~loops, Kernel("huber", options.huber_scale)))
    return final


def _termination(summary: pyceres.SolverSummary) -> str:
    """Ceres' termination type as a word (``CONVERGENCE``, ``NO_CONVERGENCE``, ...)."""
    return str(summary.termination_type).rsplit(".", 1)[-1]


def optimize_pose_graph(
    graph: PoseGraph,
    options: OptimizerOptions | None = None,
    new_loops: NDArray[np.bool_] | None = None,
    clusters: IntArray | None = None,
    merged_on: NDArray[np.bool_] | None = None,
) -> OptimizationResult:
    """Optimise ``graph`` with Ceres (sparse normal Cholesky, dynamic sparsity).

    The graph's fixed vertices stay put; a connected component without a fixed vertex has its
    first vertex fixed (the gauge). Headings are unconstrained during the solve (residual angles
    are wrapped) and wrapped to ``[-pi, pi)`` in the result. With a loop model the loop
    closures take its kernel, solved by iteratively reweighted least squares
    (:mod:`cogmap_core.robust`) from the given poses. When it rejects some of the loop
    closures ``new_loops`` (a map passes those added since its last optimisation), the
    hypothesis that they are true is solved too -- from the same start, those links under the
    convex Huber kernel first, so that a drifted estimate cannot hide them -- and the solution
    of lower robust cost is kept: the maximum a posteriori choice between "they are false" and
    "the map drifted". Costs are the final kernel's.

    ``clusters``: each edge's cluster id (-1 for odometry). With them, that hypothesis is not
    taken, whatever its cost, when it has one cluster overrule several
    (:func:`~cogmap_core.cluster_consistency.overrules_several`). ``merged_on``: the loop
    closures merges rest on; nor is it taken when it rejects one of them
    (:func:`~cogmap_core.cluster_consistency.overrules_a_merge`).

    Raises:
        OptimizationError: non-finite poses or measurements, or Ceres failed.

    """
    options = options or OptimizerOptions()
    started = time.perf_counter()
    if not (np.isfinite(graph.poses).all() and np.isfinite(graph.measurements).all()):
        raise OptimizationError("the pose graph has NaN or infinite poses or measurements")
    n, e = graph.num_vertices, graph.num_edges
    adjacency = _adjacency(graph)
    fixed = _gauge_fixed(graph, adjacency) if n else graph.fixed
    final_losses = _final_losses(graph, options)
    if e == 0 or fixed.all() or options.max_iterations == 0:
        initial_cost = graph_cost(graph, losses=final_losses)
        poses = graph.poses.copy()
        poses[:, 2] = wrap_angle(poses[:, 2])
        return OptimizationResult(
            poses,
            initial_cost,
            initial_cost,
            0,
            time.perf_counter() - started,
            "NO_PROBLEM",
            _rejected(graph, poses, options),
        )

    # Ceres reports the cost at the start point; it is computed here only when it decides the
    # initialisation or when the start point is not the given poses (LAGO).
    initial_cost = math.nan
    use_lago = options.initialization == "lago"
    if options.initialization == "auto":
        initial_cost = graph_cost(graph, losses=final_losses)
        use_lago = initial_cost > AUTO_LAGO_COST_PER_EDGE * e
    if use_lago:
        if math.isnan(initial_cost):
            initial_cost = graph_cost(graph, losses=final_losses)
        work = graph.copy()
        work.fixed = fixed
        with np.errstate(over="ignore", invalid="ignore"):
            start = lago_initialization(work)
        if not np.isfinite(start).all():
            raise OptimizationError(
                "the LAGO initialisation overflowed: the graph's values are too large; rescale "
                "the graph, or start from its own poses (initialization 'none')"
            )
    else:
        start = graph.poses

    # Ceres works in ``poses``: the vertices in the order ``perm`` (vertex ``perm[k]`` at row
    # ``k``), so that the chunks hold vertices that the edges join; ``poses[inverse]`` is the
    # estimate in the graph's order.
    perm = _vertex_order(adjacency)
    inverse = np.empty(n, dtype=np.int64)
    inverse[perm] = np.arange(n)
    poses = np.ascontiguousarray(start[perm], dtype=np.float64)
    bounds = _chunk_bounds(n, fixed[perm], options.chunk_size)
    chunk_start = np.array([a for a, _ in bounds], dtype=np.int64)
    chunk_len = np.array([b - a for a, b in bounds], dtype=np.int64)
    chunk_of = np.repeat(np.arange(len(bounds), dtype=np.int64), chunk_len)
    local_from, local_to = inverse[graph.edge_from], inverse[graph.edge_to]
    ci, cj = chunk_of[local_from], chunk_of[local_to]
    lo, hi = np.minimum(ci, cj), np.maximum(ci, cj)
    order = np.argsort(lo * len(bounds) + hi, kind="stable")
    edge_from, edge_to = local_from[order], local_to[order]
    model = EdgeModel(graph.measurements[order], graph.information[order])
    blocks = [poses[a:b].reshape(-1) for a, b in bounds]
    sizes = [3 * (b - a) for a, b in bounds]
    plan = plan_groups(edge_from, edge_to, chunk_of, chunk_start, chunk_len)

    def sorted_losses(losses: EdgeLosses) -> EdgeLosses:
        return [subset_loss(rows, kernel, order) for rows, kernel in losses]

    snapshot = Snapshot(
        poses, edge_from, edge_to, model, sorted_losses(final_losses), plan, len(bounds)
    )

    problem = pyceres.Problem()
    problem.add_residual_block(SnapshotCost(snapshot, sizes), None, blocks)
    for group, chunks in enumerate(plan.group_chunks):
        problem.add_residual_block(
            EdgeGroupCost(snapshot, plan, group, [sizes[c] for c in chunks]),
            None,
            [blocks[c] for c in chunks],
        )
    for c, (a, b) in enumerate(bounds):
        if b - a == 1 and fixed[perm[a]]:
            problem.set_parameter_block_constant(blocks[c])

    solver_options = pyceres.SolverOptions()
    solver_options.linear_solver_type = pyceres.LinearSolverType.SPARSE_NORMAL_CHOLESKY
    solver_options.dynamic_sparsity = True
    solver_options.num_threads = 1  # the Python callbacks hold the GIL anyway
    solver_options.max_num_iterations = options.max_iterations
    solver_options.function_tolerance = options.function_tolerance
    solver_options.initial_trust_region_radius = 1e8
    solver_options.logging_type = pyceres.LoggingType.SILENT
    loops = graph.loop_closures()
    edge_residuals = _EdgeResiduals(graph)
    rest = list(final_losses[1:])  # the Huber loss of the other edges, if any

    def solve(reweighting: Reweighting | None) -> tuple[int, str, float, float]:
        """Run Ceres once, or IRLS rounds: iterations, termination, Ceres' costs (once)."""
        if reweighting is None:
            summary = pyceres.SolverSummary()
            pyceres.solve(solver_options, problem, summary)
            check(summary)
            # Ceres' cost is the robust cost itself (the snapshot residual is zero)
            costs = float(summary.initial_cost), float(summary.final_cost)
            return steps(summary), _termination(summary), *costs
        count = 0
        solver_options.max_num_iterations = min(IRLS_ITERATIONS, options.max_iterations)
        while True:  # one round of IRLS: the loop closures' weights, fixed
            res = edge_residuals.at(poses[inverse])
            weights = reweighting.next(_chi2_of(res), _cost_of(res, final_losses))
            if weights is None:
                break
            snapshot.losses = sorted_losses([(loops, Weights(weights)), *rest])
            snapshot.chunk_bytes = [None] * len(bounds)  # the cost changed: no stale snapshot
            summary = pyceres.SolverSummary()
            pyceres.solve(solver_options, problem, summary)
            check(summary)
            count += steps(summary)
        termination = "CONVERGENCE" if reweighting.converged else "NO_CONVERGENCE"
        return count, termination, math.nan, math.nan

    def check(summary: pyceres.SolverSummary) -> None:
        if _termination(summary) == "FAILURE" or not np.isfinite(poses).all():
            raise OptimizationError(f"Ceres failed: {' '.join(str(summary.message).split())}")

    def steps(summary: pyceres.SolverSummary) -> int:
        # Ceres counts the evaluation at the start point as a successful step: leave it out.
        return int(summary.num_successful_steps + summary.num_unsuccessful_steps) - 1

    reweightings = 0
    if options.loop_model is None or not loops.any():
        iterations, termination, ceres_initial, final_cost = solve(None)
        if not use_lago:
            initial_cost = ceres_initial
    else:
        start = poses.copy()
        reweighting = Reweighting(options.loop_model, loops)
        iterations, termination, _, _ = solve(reweighting)
        reweightings = reweighting.rounds
        res = edge_residuals.at(poses[inverse])
        final_cost = _cost_of(res, final_losses)
        doubted = None
        if new_loops is not None:
            rejected = loops & options.loop_model.final_kernel.rejects(_chi2_of(res))
            doubted = loops & new_loops & rejected
        if doubted is not None and doubted.any():
            # The other hypothesis: the new links it rejected are true and the start is only
            # drifted. From the same start, those links are solved under the convex Huber
            # kernel (the other loop closures keep their weights at the start), then IRLS goes
            # on as before; the solution of lower robust cost is kept -- unless it has one
            # cluster overrule several (cogmap_core/cluster_consistency.py).
            kept = poses.copy()
            poses[:] = start
            kernel = options.loop_model.final_kernel
            at_start = _chi2_of(edge_residuals.at(start[inverse]))
            weights = drop_small(np.where(loops, kernel.weight(at_start), 1.0))
            convex_losses: EdgeLosses = [
                (doubted, Kernel("huber", kernel.scale)),
                (loops & ~doubted, Weights(weights)),
                *rest,
            ]
            snapshot.losses = sorted_losses(convex_losses)
            snapshot.chunk_bytes = [None] * len(bounds)
            solver_options.max_num_iterations = options.max_iterations
            convex, _, _, _ = solve(None)
            hypothesis = Reweighting(options.loop_model, loops)
            more, other_termination, _, _ = solve(hypothesis)
            iterations += convex + more
            reweightings += hypothesis.rounds
            other_residuals = edge_residuals.at(poses[inverse])
            other_cost = _cost_of(other_residuals, final_losses)
            accepted = loops & ~new_loops & ~kernel.rejects(at_start)
            other_rejects = kernel.rejects(_chi2_of(other_residuals))
            vetoed = clusters is not None and overrules_several(
                clusters, loops, loops & new_loops, accepted, other_rejects
            )
            if merged_on is not None and not vetoed:
                vetoed = overrules_a_merge(merged_on, accepted, other_rejects)
            if vetoed:
                other_cost = math.inf
            if other_cost < final_cost:
                final_cost, termination = other_cost, other_termination
            else:
                poses[:] = kept
    poses = poses[inverse]
    poses[:, 2] = wrap_angle(poses[:, 2])
    if math.isnan(initial_cost):
        initial_cost = _cost_of(edge_residuals.at(graph.poses), final_losses)
    return OptimizationResult(
        poses=poses,
        initial_cost=initial_cost,
        final_cost=final_cost,
        iterations=iterations,
        wall_s=time.perf_counter() - started,
        termination=termination,
        rejected=_rejected(graph, poses, options),
        reweightings=reweightings,
    )


def rejected_loop_closures(
    graph: PoseGraph, model: LoopClosureModel | None, poses: FloatArray | None = None
) -> NDArray[np.bool_]:
    """``(E,)`` loop closures the loop model rejects at ``poses`` (default: the graph's).

    Rejected: chi^2 past the model's kernel scale; none without a model (the paper's Huber
    rejects nothing).
    """
    if model is None or graph.num_edges == 0:
        return np.zeros(graph.num_edges, dtype=bool)
    return graph.loop_closures() & model.final_kernel.rejects(chi2(graph, poses))


def _rejected(graph: PoseGraph, poses: FloatArray, options: OptimizerOptions) -> NDArray[np.bool_]:
    """Loop closures the options' loop model rejects at ``poses``."""
    return rejected_loop_closures(graph, options.loop_model, poses)
