"""The robust loop-closure model: kernels, reweighting, drifted starts, false links, CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.cli import main
from cogmap_core.config import MapParams
from cogmap_core.errors import ParameterError
from cogmap_core.g2o import read_g2o, write_g2o
from cogmap_core.geometry import between, compose
from cogmap_core.optimizer import OptimizerOptions, chi2, graph_cost, optimize_pose_graph
from cogmap_core.posegraph import PoseGraph
from cogmap_core.robust import (
    DEFAULT_LOOP_KERNEL,
    DROP_WEIGHT,
    MAP_IRLS_TOLERANCE,
    Kernel,
    LoopClosureModel,
    Reweighting,
    Weights,
    apply_kernel,
    loop_closure_model,
)
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS


# ------------------------------------------------------------------------------- kernels
@pytest.mark.parametrize(
    ("name", "s", "rho", "weight"),
    [
        ("huber", 0.25, 0.25, 1.0),
        ("huber", 4.0, 2.0 * 1.0 * 2.0 - 1.0, 0.5),
        ("cauchy", 3.0, math.log(4.0), 0.25),
        ("geman_mcclure", 3.0, 0.75, 1.0 / 16.0),
        ("dcs", 0.5, 0.5, 1.0),
        ("dcs", 3.0, 3.0 * 0.25, 0.25),  # scaling 2 / (1 + 3) = 0.5, squared
    ],
)
def test_kernel_values_and_weights(name, s, rho, weight):
    value, w = Kernel(name, 1.0).evaluate(np.array([s]))
    assert value[0] == pytest.approx(rho, rel=1e-12)
    assert w[0] == pytest.approx(weight, rel=1e-12)


def test_max_mixture_switches_to_the_null_hypothesis_where_it_is_likelier():
    kernel = Kernel("max_mixture")
    # null hypothesis: 10 sigma wide, 10 % of the mass, in 3 dimensions
    offset = 2.0 * (3.0 * math.log(10.0) + math.log(0.9 / 0.1))  # 18.21...
    s = np.array([0.0, 1.0, 18.0, 30.0, 1000.0])
    rho, weight = kernel.evaluate(s)
    np.testing.assert_allclose(rho, [0.0, 1.0, 18.0, 0.3 + offset, 10.0 + offset])
    np.testing.assert_allclose(weight, [1.0, 1.0, 1.0, 0.01, 0.01])
    assert kernel.rejects(s).tolist() == [False, False, False, True, True]


def test_geman_mcclure_rejects_past_its_scale():
    kernel = Kernel("geman_mcclure", 2.0)
    assert kernel.rejects(np.array([3.9, 4.0, 4.1])).tolist() == [False, False, True]


@pytest.mark.parametrize(
    ("name", "scale", "message"),
    [("tukey", 1.0, "unknown"), ("cauchy", 0.0, "must be > 0"), ("cauchy", math.inf, "> 0")],
)
def test_kernels_are_validated(name, scale, message):
    with pytest.raises(ParameterError, match=message):
        Kernel(name, scale)


def test_graduation_needs_geman_mcclure():
    with pytest.raises(ParameterError, match="graduated non-convexity needs"):
        LoopClosureModel("dcs", graduated=True)


def test_weights_scale_residuals_and_jacobians_by_their_root():
    rng = np.random.default_rng(1)
    res, jac = rng.normal(size=(4, 3)), rng.normal(size=(4, 2, 3, 3))
    w = np.array([1.0, 0.25, 0.0, 4.0])
    rows = np.array([True, True, True, False])
    out, out_jac = apply_kernel(res, jac, Weights(w), rows)
    np.testing.assert_array_equal(out[:, 0], res[:, 0] * np.array([1.0, 0.5, 0.0, 1.0]))
    np.testing.assert_array_equal(out_jac[1], 0.5 * jac[1])
    np.testing.assert_array_equal(out_jac[3], jac[3])


def test_exact_kernel_residual_squares_to_rho_and_its_jacobian_is_the_derivative():
    rng = np.random.default_rng(2)
    kernel = Kernel("geman_mcclure", 0.7)
    res = rng.normal(size=(5, 3))
    jac = rng.normal(size=(5, 2, 3, 3))
    out, out_jac = apply_kernel(res, jac, kernel, None)
    rho, _ = kernel.evaluate(np.einsum("ka,ka->k", res, res))
    np.testing.assert_allclose(np.einsum("ka,ka->k", out, out), rho, rtol=1e-12)
    # d r~ / d x along a direction, against central differences of r~(r + J dx)
    dx = rng.normal(size=3)
    h = 1e-6
    plus, _ = apply_kernel(res + h * jac[:, 0] @ dx, None, kernel, None)
    minus, _ = apply_kernel(res - h * jac[:, 0] @ dx, None, kernel, None)
    np.testing.assert_allclose(out_jac[:, 0] @ dx, (plus - minus) / (2 * h), atol=1e-7)


def test_reweighting_drops_tiny_weights_and_stops_when_the_cost_settles():
    model = LoopClosureModel("geman_mcclure", 1.0)
    loops = np.array([False, True, True])
    schedule = Reweighting(model, loops)
    weights = schedule.next(np.array([100.0, 0.0, 1e7]), 10.0)
    assert weights is not None
    assert weights.tolist() == [1.0, 1.0, 0.0]  # (1 / (1 + 1e7))^2 < DROP_WEIGHT
    assert (1.0 / (1.0 + 1e7)) ** 2 < DROP_WEIGHT
    assert schedule.next(np.array([100.0, 0.0, 1e7]), 10.0) is None  # same cost: converged
    assert schedule.converged and schedule.rounds == 1


def test_reweighting_stops_at_the_models_tolerance():
    loops = np.array([True])
    for tolerance, rounds in ((1e-3, 1), (1e-5, 2)):
        schedule = Reweighting(LoopClosureModel(tolerance=tolerance), loops)
        assert schedule.next(np.array([0.5]), 10.0) is not None
        if rounds == 2:  # a change of 0.05 % is past 1e-5 but within 1e-3
            assert schedule.next(np.array([0.5]), 10.005) is not None
        assert schedule.next(np.array([0.5]), 10.0049) is None
        assert schedule.rounds == rounds
    with pytest.raises(ParameterError, match="IRLS tolerance 0 must be in"):
        LoopClosureModel(tolerance=0)


def test_loop_model_codes():
    assert loop_closure_model(0, 1.0) is None
    assert loop_closure_model(2, 1.5) == LoopClosureModel("geman_mcclure", 1.5)
    assert loop_closure_model(5, 1.0) == LoopClosureModel("geman_mcclure", 1.0, graduated=True)
    # the maps' scale is in link sigmas: 3 x 3 cm for a bag, 3 x 0.5 m for a log
    bag, log = MapParams().loop_closure_model(), LOG_MAP_PARAMS.loop_closure_model()
    assert bag is not None and log is not None
    assert (bag.kernel, bag.graduated, bag.tolerance) == ("geman_mcclure", False, 1e-3)
    assert bag.scale == pytest.approx(0.09, abs=1e-15) and MAP_IRLS_TOLERANCE == 1e-3
    assert log.scale == pytest.approx(1.5, abs=1e-15) and log.kernel == "geman_mcclure"
    with pytest.raises(ParameterError, match="loop_model=2.5 is out of range"):
        MapParams(loop_model=2.5)
    with pytest.raises(ParameterError, match="loop_model=True is not a number"):
        MapParams(loop_model=True)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------- graphs
def square_laps(
    laps: int = 3, side: int = 10, heading_bias: float = 0.0
) -> tuple[PoseGraph, np.ndarray]:
    """A robot driving ``laps`` laps of a square, one vertex per metre, exact loop closures.

    Odometry is exact but for a heading bias per step (the start is the odometry chain);
    every vertex of lap k > 0 is closed to the same corner of lap 0.
    """
    step = np.array([1.0, 0.0, 0.0])
    turn = np.array([1.0, 0.0, math.pi / 2])
    per_lap = 4 * side
    n = laps * per_lap + 1
    truth = np.zeros((n, 3))
    moves = []
    for k in range(1, n):
        move = turn if k % side == 0 else step
        truth[k] = compose(truth[k - 1], move)
        moves.append(move)
    odometry = np.array(moves) + [0.0, 0.0, heading_bias]
    start = np.zeros((n, 3))
    for k in range(1, n):
        start[k] = compose(start[k - 1], odometry[k - 1])
    frm = list(range(n - 1))
    to = list(range(1, n))
    meas = list(odometry)
    for k in range(per_lap, n):
        frm.append(k % per_lap)
        to.append(k)
        meas.append(between(truth[k % per_lap], truth[k]))
    e = len(frm)
    info = np.repeat(np.diag([100.0, 100.0, 400.0])[None], e, axis=0)
    info[n - 1 :] = np.diag([4.0, 4.0, 4.0])  # loop closures: sigma 0.5
    loops = np.zeros(e, dtype=bool)
    loops[n - 1 :] = True
    return PoseGraph(np.arange(n), start, frm, to, meas, info, loop_closure=loops), truth


def add_false_links(graph: PoseGraph, count: int, seed: int) -> tuple[PoseGraph, np.ndarray]:
    """``graph`` plus ``count`` false loop closures between random far-apart vertices."""
    rng = np.random.default_rng(seed)
    n = graph.num_vertices
    a = rng.integers(0, n, count)
    b = (a + rng.integers(5, n - 5, count)) % n
    meas = np.column_stack(
        [rng.normal(0, 1, count), rng.normal(0, 1, count), rng.uniform(-3, 3, count)]
    )
    info = np.repeat(np.diag([4.0, 4.0, 4.0])[None], count, axis=0)
    false = np.r_[np.zeros(graph.num_edges, dtype=bool), np.ones(count, dtype=bool)]
    return (
        PoseGraph(
            graph.vertex_ids,
            graph.poses,
            np.r_[graph.edge_from, a],
            np.r_[graph.edge_to, b],
            np.r_[graph.measurements, meas],
            np.r_[graph.information, info],
            graph.fixed.copy(),
            np.r_[graph.loop_closures(), np.ones(count, dtype=bool)],
        ),
        false,
    )


def test_geman_mcclure_rejects_every_false_link_and_recovers_the_truth():
    clean, truth = square_laps(laps=3)
    graph, false = add_false_links(clean, 12, seed=3)
    huber = optimize_pose_graph(graph, OptimizerOptions(huber_scale=1.0))
    result = optimize_pose_graph(graph, OptimizerOptions(loop_model=LoopClosureModel()))
    assert result.rejected is not None
    assert result.rejected.tolist() == false.tolist()  # exactly the false ones
    assert result.num_rejected == 12
    assert result.termination == "CONVERGENCE"
    assert_poses_close(result.poses, truth, 5e-3)  # rejected links still pull a little
    assert np.abs(huber.poses[:, :2] - truth[:, :2]).max() > 0.05  # Huber alone is pulled off
    # the reported cost is the robust one at the result
    assert result.final_cost == pytest.approx(
        graph_cost(graph, result.poses, losses=[(graph.loop_closures(), Kernel("geman_mcclure"))]),
        rel=1e-9,
    )


def assert_poses_close(poses: np.ndarray, expected: np.ndarray, atol: float) -> None:
    np.testing.assert_allclose(poses[:, :2], expected[:, :2], atol=atol)
    heading = (poses[:, 2] - expected[:, 2] + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(heading, 0.0, atol=atol)


def test_without_false_links_dcs_is_least_squares():
    """Below its scale DCS weighs a link fully: a graph without outliers keeps its optimum."""
    clean, _ = square_laps(laps=2, heading_bias=0.002)
    plain = optimize_pose_graph(clean, OptimizerOptions())
    assert chi2(clean, plain.poses)[clean.loop_closures()].max() < 1.0
    dcs = optimize_pose_graph(clean, OptimizerOptions(loop_model=LoopClosureModel("dcs")))
    assert_poses_close(dcs.poses, plain.poses, 1e-4)
    assert dcs.final_cost == pytest.approx(plain.final_cost, rel=1e-6)
    gm = optimize_pose_graph(clean, OptimizerOptions(loop_model=LoopClosureModel()))
    assert gm.num_rejected == 0
    assert_poses_close(gm.poses, plain.poses, 2e-3)  # inliers weigh a bit less


def test_new_links_on_a_drifted_start_are_weighed_as_true_or_false():
    """The hypothesis that new links are true is solved too; the lower robust cost wins."""
    clean, _ = square_laps(laps=2, heading_bias=0.02)  # 0.02 rad a metre: 9 m of drift
    optimum = optimize_pose_graph(clean, OptimizerOptions()).poses
    start_chi2 = chi2(clean)[clean.loop_closures()]
    assert np.sqrt(start_chi2.max()) > 10  # the true links look like outliers at the start
    model = OptimizerOptions(loop_model=LoopClosureModel())
    alone = optimize_pose_graph(clean, model)
    assert alone.num_rejected > 0  # the kernel from a drifted start rejects true links
    weighed = optimize_pose_graph(clean, model, new_loops=clean.loop_closures())
    assert weighed.num_rejected == 0
    assert weighed.final_cost < alone.final_cost
    np.testing.assert_allclose(weighed.poses[:, :2], optimum[:, :2], atol=0.06)
    # false new links: "they are true" costs more than rejecting them
    noisy, false = add_false_links(square_laps(laps=2)[0], 6, seed=4)
    result = optimize_pose_graph(noisy, model, new_loops=noisy.loop_closures())
    assert result.rejected.tolist() == false.tolist()


def test_graduated_non_convexity_from_least_squares():
    clean, _ = square_laps(laps=3)
    graph, false = add_false_links(clean, 3, seed=5)
    result = optimize_pose_graph(
        graph, OptimizerOptions(loop_model=LoopClosureModel(graduated=True))
    )
    assert result.rejected.tolist() == false.tolist()
    assert result.reweightings > 5  # the graduation's stages, then IRLS at the kernel


def test_cli_robust_adds_the_loop_closures_and_rejections(tmp_path, capsys):
    clean, _ = square_laps(laps=3)
    graph, _ = add_false_links(clean, 7, seed=6)
    graph.loop_closure = None  # g2o files: non-consecutive ids are the loop closures
    source = tmp_path / "square.g2o"
    write_g2o(graph, source)
    loops = int(read_g2o(source).loop_closures().sum())
    assert loops == int(clean.loop_closures().sum()) + 7
    out = tmp_path / "out.g2o"
    assert main(["optimize", str(source), str(out), "--robust", "--init", "none"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["loop_closures"] == loops
    assert report["loop_closures_rejected"] == 7
    assert DEFAULT_LOOP_KERNEL == "dcs"
    command = ["optimize", str(source), str(out), "--robust", "geman_mcclure", "--init", "none"]
    assert main(command) == 0
    assert json.loads(capsys.readouterr().out)["loop_closures_rejected"] == 7
    assert main(["optimize", str(source), str(out), "--init", "none"]) == 0
    assert "loop_closures" not in json.loads(capsys.readouterr().out)


def test_cli_refuses_an_unknown_kernel(tmp_path, capsys):
    clean, _ = square_laps(laps=2)
    source = tmp_path / "g.g2o"
    write_g2o(clean, source)
    with pytest.raises(SystemExit) as exit_info:
        main(["optimize", str(source), str(tmp_path / "o.g2o"), "--robust", "tukey"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'tukey'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("mode", "rejected"),
    [("standard", [(29, 70), (70, 31)]), ("scene_integration", [(29, 70), (70, 31)])],
)
def test_a_map_rejects_the_false_relocalisation_it_was_made_to_follow(mode, rejected):
    # the relocalisation test off: the map follows the false claim (29 -> 70, then back to 31)
    from tests.test_relocalisation import NO_GATE, PAPER, build, false_relocalisation_lap

    loop, wrong = false_relocalisation_lap()
    assert wrong == 70
    cmap = build(mode, loop.s.events, **NO_GATE)
    snap = cmap.snapshot()
    mask = cmap.rejected_loop_edges()
    pairs = list(zip(snap.edge_from[mask].tolist(), snap.edge_to[mask].tolist(), strict=True))
    assert pairs == rejected
    truth = np.array([loop.s.truth[v] for v in snap.vertex_ids.tolist()])
    assert np.abs(snap.poses[:, :2] - truth[:, :2]).max() < 1e-3  # the map stays true
    huber = build(mode, loop.s.events, **PAPER)  # the paper's map bends
    assert not huber.rejected_loop_edges().any()
    huber_snap = huber.snapshot()
    huber_truth = np.array([loop.s.truth[v] for v in huber_snap.vertex_ids.tolist()])
    assert np.abs(huber_snap.poses[:, :2] - huber_truth[:, :2]).max() > 0.1
