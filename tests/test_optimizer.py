"""The batch optimiser: residual definition, derivatives, optimum, robustness, gauge, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import least_squares

from app.cli import main
from cogmap_core import ceres_blocks, optimizer
from cogmap_core.errors import OptimizationError, ParameterError
from cogmap_core.g2o import read_g2o
from cogmap_core.geometry import compose, polar_to_relative, wrap_angle
from cogmap_core.optimizer import (
    EdgeModel,
    OptimizerOptions,
    edge_losses,
    edge_terms,
    graph_cost,
    optimize_pose_graph,
)
from cogmap_core.posegraph import PoseGraph
from cogmap_core.robust import LoopClosureModel


def random_graph(
    rng: np.random.Generator, n: int = 40, loops: int = 15
) -> tuple[PoseGraph, np.ndarray]:
    """A noisy random walk with loop closures and anisotropic information; returns graph, truth."""
    truth = np.zeros((n, 3))
    for k in range(1, n):
        step = np.array([rng.uniform(0.2, 1.0), rng.normal(0, 0.1), rng.normal(0, 0.6)])
        truth[k] = compose(truth[k - 1], step)
    pairs = [(k, k + 1) for k in range(n - 1)]
    pairs += [tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(loops)]
    i = np.array([p[0] for p in pairs])
    j = np.array([p[1] for p in pairs])
    from cogmap_core.geometry import between

    meas = between(truth[i], truth[j]) + rng.normal(0, [0.05, 0.05, 0.02], (len(pairs), 3))
    a = rng.normal(size=(len(pairs), 3, 3))
    info = a @ a.transpose(0, 2, 1) + 3 * np.eye(3)
    start = np.zeros((n, 3))
    for k in range(1, n):  # odometry chain
        start[k] = compose(start[k - 1], meas[k - 1])
    return PoseGraph(np.arange(n), start, i, j, meas, info), truth


def g2o_residual(xi, xj, z):
    """The g2o residual written directly: R_z^T (R_i^T (p_j - p_i) - t_z), wrapped angle."""
    ci, si = np.cos(xi[2]), np.sin(xi[2])
    d = xj[:2] - xi[:2]
    local = np.array([ci * d[0] + si * d[1], -si * d[0] + ci * d[1]]) - z[:2]
    cz, sz = np.cos(z[2]), np.sin(z[2])
    return np.array(
        [
            cz * local[0] + sz * local[1],
            -sz * local[0] + cz * local[1],
            wrap_angle(xj[2] - xi[2] - z[2]),
        ]
    )


def test_residual_matches_g2o_definition_and_cost():
    rng = np.random.default_rng(1)
    graph, _ = random_graph(rng, 10, 4)
    x = graph.poses + rng.normal(0, 0.3, graph.poses.shape)
    model = EdgeModel(graph.measurements, graph.information)
    res, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, None, False)
    expected_cost = 0.0
    for k in range(graph.num_edges):
        e = g2o_residual(x[graph.edge_from[k]], x[graph.edge_to[k]], graph.measurements[k])
        expected_cost += 0.5 * e @ graph.information[k] @ e
        assert res[k] @ res[k] == pytest.approx(e @ graph.information[k] @ e, rel=1e-10)
    assert graph_cost(graph, x) == pytest.approx(expected_cost, rel=1e-12)


def test_paper_world_frame_residual_has_the_same_norm():
    """f = e_j - e_i - e_ij with x_ij = d cos(theta_i + heading) equals the g2o residual in norm."""
    rng = np.random.default_rng(2)
    xi, xj = rng.normal(size=3), rng.normal(size=3)
    d, heading, facing = 0.7, 0.4, -0.9
    z = polar_to_relative(d, heading, facing)
    paper = np.array(
        [
            xj[0] - xi[0] - d * np.cos(xi[2] + heading),
            xj[1] - xi[1] - d * np.sin(xi[2] + heading),
            wrap_angle(xj[2] - xi[2] - facing),
        ]
    )
    ours = g2o_residual(xi, xj, z)
    assert np.linalg.norm(paper) == pytest.approx(np.linalg.norm(ours), rel=1e-12)


@pytest.mark.parametrize("huber", [None, 0.05, 1.0])
def test_jacobians_match_finite_differences(huber):
    rng = np.random.default_rng(3)
    graph, _ = random_graph(rng, 12, 6)
    x = graph.poses + rng.normal(0, 0.5, graph.poses.shape)
    model = EdgeModel(graph.measurements, graph.information)
    xi, xj = x[graph.edge_from], x[graph.edge_to]
    _, jac = edge_terms(xi, xj, model, edge_losses(huber), True)
    h = 1e-6
    for endpoint, base in ((0, xi), (1, xj)):
        for c in range(3):
            plus, minus = base.copy(), base.copy()
            plus[:, c] += h
            minus[:, c] -= h
            args_p = (plus, xj) if endpoint == 0 else (xi, plus)
            args_m = (minus, xj) if endpoint == 0 else (xi, minus)
            rp, _ = edge_terms(*args_p, model, edge_losses(huber), False)
            rm, _ = edge_terms(*args_m, model, edge_losses(huber), False)
            np.testing.assert_allclose(jac[:, endpoint, :, c], (rp - rm) / (2 * h), atol=1e-5)


def test_huber_residual_squared_is_rho():
    rng = np.random.default_rng(4)
    graph, _ = random_graph(rng, 20, 8)
    x = graph.poses + rng.normal(0, 0.5, graph.poses.shape)
    model = EdgeModel(graph.measurements, graph.information)
    plain, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, None, False)
    robust, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, edge_losses(0.3), False)
    s = (plain**2).sum(1)
    rho = np.where(s <= 0.09, s, 2 * 0.3 * np.sqrt(s) - 0.09)
    assert (s > 0.09).sum() > 5 and (s <= 0.09).sum() >= 0
    np.testing.assert_allclose((robust**2).sum(1), rho, rtol=1e-12)


@pytest.mark.parametrize("huber", [None, 0.5])
def test_optimum_matches_scipy_least_squares(huber):
    rng = np.random.default_rng(5)
    graph, _ = random_graph(rng, 40, 15)
    result = optimize_pose_graph(
        graph, OptimizerOptions(huber_scale=huber, function_tolerance=1e-12)
    )
    model = EdgeModel(graph.measurements, graph.information)

    def fun(v):
        x = np.vstack([graph.poses[:1], v.reshape(-1, 3)])
        r, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, edge_losses(huber), False)
        return r.ravel()

    ref = least_squares(fun, result.poses[1:].ravel(), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    ref_x = np.vstack([graph.poses[:1], ref.x.reshape(-1, 3)])
    ref_x[:, 2] = wrap_angle(ref_x[:, 2])
    assert result.final_cost == pytest.approx(ref.cost, rel=1e-9)
    np.testing.assert_allclose(result.poses[:, :2], ref_x[:, :2], atol=1e-6)
    np.testing.assert_allclose(wrap_angle(result.poses[:, 2] - ref_x[:, 2]), 0, atol=1e-6)
    np.testing.assert_array_equal(result.poses[0], graph.poses[0])  # first vertex fixed


def test_result_independent_of_chunking_and_angles_wrapped():
    rng = np.random.default_rng(6)
    graph, _ = random_graph(rng, 60, 20)
    graph.poses[:, 2] += 4 * np.pi  # headings far outside [-pi, pi)
    results = [
        optimize_pose_graph(graph, OptimizerOptions(chunk_size=k, function_tolerance=1e-12))
        for k in (1, 3, 32, 1000)
    ]
    for r in results[1:]:
        np.testing.assert_allclose(r.poses, results[0].poses, atol=1e-7)
        assert r.final_cost == pytest.approx(results[0].final_cost, rel=1e-9)
    for r in results:
        assert (r.poses[:, 2] >= -np.pi).all() and (r.poses[:, 2] < np.pi).all()


def laps_graph(laps: int, per_lap: int) -> PoseGraph:
    """``laps`` laps of a closed ``per_lap``-gon, each vertex closed to the same corner a lap on.

    The start is the odometry chain with a heading bias (so the loop closures are needed), and
    every third loop closure is false.
    """
    n = laps * per_lap
    angle = 2 * np.pi / per_lap
    side = 2 * np.sin(angle / 2)
    step = np.array([side, 0.0, angle])
    frm = list(range(n - 1))
    to = list(range(1, n))
    meas = [step] * (n - 1)
    for k in range(n - per_lap):
        frm.append(k)
        to.append(k + per_lap)
        meas.append(np.array([0.0, 0.0, 0.0]) if k % 3 else np.array([0.7, -0.4, 0.5]))
    start = np.zeros((n, 3))
    for k in range(1, n):
        start[k] = compose(start[k - 1], step + [0.0, 0.0, 0.01])
    e = len(frm)
    loops = np.arange(e) >= n - 1
    info = np.repeat(np.diag([100.0, 100.0, 400.0])[None], e, axis=0)
    info[loops] = np.diag([4.0, 4.0, 4.0])
    return PoseGraph(np.arange(n), start, frm, to, np.array(meas), info, loop_closure=loops)


def bandwidth(graph: PoseGraph, order: np.ndarray) -> int:
    """The largest distance in ``order`` between two vertices an edge joins."""
    position = np.empty(graph.num_vertices, dtype=np.int64)
    position[order] = np.arange(graph.num_vertices)
    return int(np.abs(position[graph.edge_from] - position[graph.edge_to]).max())


@pytest.mark.parametrize("laps", [2, 3, 5])
def test_vertex_order_puts_the_laps_side_by_side(laps):
    """Loop closures join vertices a lap apart; in Ceres' order they are near neighbours."""
    graph = laps_graph(laps, 40)
    order = optimizer._vertex_order(optimizer._adjacency(graph))
    assert sorted(order.tolist()) == list(range(graph.num_vertices))
    assert bandwidth(graph, np.arange(graph.num_vertices)) == 40  # index order: a lap apart
    # each breadth-first level of the ladder holds at most two vertices of each lap
    assert bandwidth(graph, order) <= 2 * laps + 1


def test_result_independent_of_the_vertex_order(monkeypatch):
    """Ceres works in its own vertex order; the result is the one of the graph's own order.

    With the robust loop model: its reweighting, and the hypothesis that rejected new links are
    true (every third link here is false).
    """
    graph = laps_graph(3, 40)
    options = OptimizerOptions(loop_model=LoopClosureModel(scale=0.09), huber_scale=1.0)
    reordered = optimize_pose_graph(graph, options, new_loops=graph.loop_closures())
    monkeypatch.setattr(optimizer, "_vertex_order", lambda a: np.arange(a.shape[0]))
    plain = optimize_pose_graph(graph, options, new_loops=graph.loop_closures())
    assert bandwidth(graph, np.arange(graph.num_vertices)) == 40
    assert reordered.num_rejected == plain.num_rejected > 0
    np.testing.assert_array_equal(reordered.rejected, plain.rejected)
    assert (reordered.iterations, reordered.reweightings) == (plain.iterations, plain.reweightings)
    np.testing.assert_allclose(reordered.poses, plain.poses, rtol=0, atol=1e-9)
    assert reordered.final_cost == pytest.approx(plain.final_cost, rel=1e-9)
    assert reordered.initial_cost == plain.initial_cost
    np.testing.assert_array_equal(reordered.poses[0], graph.poses[0])  # the gauge: vertex 0


def test_an_edge_group_away_from_the_snapshot_computes_its_own_edges(monkeypatch):
    """A residual block copies the snapshot only when Ceres evaluates it at the snapshot's point.

    Evaluated elsewhere (at a point the snapshot did not take, or for Jacobians the snapshot
    does not hold) it computes its own edges: the same values as from a snapshot taken there.
    """
    groups: list[ceres_blocks.EdgeGroupCost] = []
    real_init = ceres_blocks.EdgeGroupCost.__init__

    def keep(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        groups.append(self)

    monkeypatch.setattr(ceres_blocks.EdgeGroupCost, "__init__", keep)
    graph = laps_graph(2, 12)
    optimize_pose_graph(graph, OptimizerOptions(chunk_size=4, huber_scale=0.5))
    snapshot = groups[0].snapshot
    rng = np.random.default_rng(1)
    point = snapshot.poses + rng.normal(0, 0.3, snapshot.poses.shape)
    chunks = [point[a:b].reshape(-1) for a, b in chunk_spans(snapshot, groups)]
    two = [g for g in groups if len(g.chunks) == 2]
    assert two and len(two) < len(groups)
    for with_jacobians in (False, True):
        snapshot.take([c.copy() for c in chunks], with_jacobians)
        for group in groups:
            values = [chunks[c] for c in group.chunks]
            fresh, fresh_jac = group.evaluate(*values)
            snapshot.chunk_bytes = [None] * len(chunks)  # the snapshot is elsewhere now
            own, own_jac = group.evaluate(*values)
            np.testing.assert_allclose(own, fresh, rtol=0, atol=1e-12)
            for a, b in zip(own_jac, fresh_jac, strict=True):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
            snapshot.take([c.copy() for c in chunks], with_jacobians)
        # the snapshot's residuals are the edges' own (sorted as the groups hold them)
        assert not np.array_equal(snapshot.residuals, 0)


def chunk_spans(snapshot: ceres_blocks.Snapshot, groups: list) -> list[tuple[int, int]]:
    """The chunks' row ranges in the snapshot's poses, from the groups' Jacobian layout."""
    count = len(snapshot.chunk_bytes)
    sizes = [0] * count
    for group in groups:
        for chunk, (a, b) in zip(group.chunks, group.spans, strict=True):
            sizes[chunk] = (b - a) // group.num_residuals() // 3
    ends = np.cumsum(sizes)
    return [(int(e - s), int(e)) for s, e in zip(sizes, ends, strict=True)]


def test_huber_limits_the_damage_of_an_outlier():
    rng = np.random.default_rng(7)
    graph, truth = random_graph(rng, 50, 10)
    from cogmap_core.geometry import between

    # exact measurements, then one grossly wrong loop closure
    graph.measurements = between(truth[graph.edge_from], truth[graph.edge_to])
    graph.information = np.broadcast_to(np.eye(3), graph.information.shape).copy()
    graph.measurements[-1] += [3.0, -2.0, 1.0]
    plain = optimize_pose_graph(graph, OptimizerOptions(initialization="lago"))
    robust = optimize_pose_graph(graph, OptimizerOptions(initialization="lago", huber_scale=0.05))
    err_plain = np.abs(plain.poses[:, :2] - truth[:, :2]).max()
    err_robust = np.abs(robust.poses[:, :2] - truth[:, :2]).max()
    assert err_robust < 0.2 * err_plain
    assert err_plain > 0.1


def test_gauge_each_component_keeps_its_first_vertex():
    rng = np.random.default_rng(8)
    a, _ = random_graph(rng, 10, 3)
    b, _ = random_graph(rng, 10, 3)
    b.poses += [5.0, 5.0, 1.0]
    graph = PoseGraph(
        np.arange(20),
        np.vstack([a.poses, b.poses]),
        np.r_[a.edge_from, b.edge_from + 10],
        np.r_[a.edge_to, b.edge_to + 10],
        np.vstack([a.measurements, b.measurements]),
        np.vstack([a.information, b.information]),
    )
    r = optimize_pose_graph(graph)
    np.testing.assert_allclose(r.poses[[0, 10]], wrap_angle_rows(graph.poses[[0, 10]]))
    assert r.final_cost < r.initial_cost


def wrap_angle_rows(p):
    q = p.copy()
    q[:, 2] = wrap_angle(q[:, 2])
    return q


def test_benchmark_graph_reaches_reference_optima(data_dir):
    """REFERENCE.md: g2o-residual optimum from odometry start 385.332 (a local minimum)."""
    graph = read_g2o(data_dir / "MIT.g2o")
    warm = optimize_pose_graph(graph, OptimizerOptions(initialization="none"))
    assert warm.final_cost == pytest.approx(385.332, rel=1e-3)
    lago = optimize_pose_graph(graph, OptimizerOptions(initialization="lago"))
    assert lago.final_cost < 21.0  # LAGO's start avoids that local minimum
    assert lago.initial_cost == pytest.approx(warm.initial_cost, rel=1e-12)  # the file's poses


def test_non_finite_input_is_refused():
    rng = np.random.default_rng(9)
    graph, _ = random_graph(rng, 5, 1)
    graph.poses[2, 0] = np.nan
    with pytest.raises(OptimizationError, match="NaN or infinite"):
        optimize_pose_graph(graph)


def test_options_are_validated():
    with pytest.raises(ParameterError, match="huber_scale"):
        OptimizerOptions(huber_scale=0.0)
    with pytest.raises(ParameterError, match="initialization"):
        OptimizerOptions(initialization="magic")  # type: ignore[arg-type]


def test_cli_prints_one_json_line_and_writes_result(tmp_path, capsys, data_dir):
    out = tmp_path / "mit_opt.g2o"
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(out), "--init", "none"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    report = json.loads(lines[0])
    assert set(report) == {
        "vertices",
        "edges",
        "initial_cost",
        "final_cost",
        "iterations",
        "wall_s",
    }
    assert (report["vertices"], report["edges"]) == (808, 827)
    assert report["final_cost"] == pytest.approx(385.332, rel=1e-3)
    optimised = read_g2o(out)
    assert graph_cost(optimised) == pytest.approx(report["final_cost"], rel=1e-9)
    # --huber changes the cost definition to the robust one
    assert main(["optimize", str(data_dir / "MIT.g2o"), str(out), "--huber", "1.0"]) == 0
    robust = json.loads(capsys.readouterr().out)
    assert robust["initial_cost"] < report["initial_cost"]
