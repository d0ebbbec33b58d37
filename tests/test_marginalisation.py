"""A merged revisit run's evidence kept (``cogmap_core.marginalisation``), on front-end events.

The corridor below is a linear-Gaussian problem: the robot drives along x (headings 0 or pi,
exact), its odometry off by a few per cent in length only. The standard map keeps the revisit
run's vertices; the scene-integration map merges them and keeps their chain as one evidence
edge. Marginalising a chain is exact there, so both maps must put every first-visit vertex at
the same place -- and without the evidence edge they must not.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core.cognitive_map import CognitiveMap
from cogmap_core.config import MapParams
from cogmap_core.geometry import (
    compose_covariance,
    compose_scalar,
    inverse_covariance,
    inverse_scalar,
    wrap_scalar,
)
from cogmap_core.map_graph import EdgeKind, MapGraph
from cogmap_core.marginalisation import chain_measurement, keep_chain_evidence
from cogmap_core.optimizer import OptimizerOptions, optimize_pose_graph
from cogmap_core.posegraph import PoseGraph
from tests.mapscript import Script

LINK_SIGMAS = (0.03, 0.1)


def _perturbed(z: tuple[float, float, float], d: np.ndarray) -> tuple[float, float, float]:
    """``z`` perturbed by ``d`` in its own frame (the optimiser's residual frame)."""
    c, s = math.cos(z[2]), math.sin(z[2])
    return (z[0] + c * d[0] - s * d[1], z[1] + s * d[0] + c * d[1], z[2] + d[2])


def _error(z: tuple[float, float, float], other: tuple[float, float, float]) -> np.ndarray:
    """The perturbation that takes ``z`` to ``other``, in ``z``'s frame."""
    c, s = math.cos(z[2]), math.sin(z[2])
    dx, dy = other[0] - z[0], other[1] - z[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_scalar(other[2] - z[2])])


def _numeric_jacobian(f, z: tuple[float, float, float]) -> np.ndarray:
    """d error(f(z), f(z perturbed by d)) / dd at 0, by central differences."""
    base, h = f(z), 1e-6
    columns = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        columns.append(
            (_error(base, f(_perturbed(z, d))) - _error(base, f(_perturbed(z, -d)))) / (2 * h)
        )
    return np.stack(columns, axis=1)


COV_A = np.array([[1e-4, 2e-5, 1e-5], [2e-5, 4e-4, -3e-5], [1e-5, -3e-5, 1e-3]])
COV_B = np.diag([2e-4, 1e-4, 3e-4])


def test_composed_covariance_is_the_first_order_propagation():
    a, b = (0.3, -0.2, 0.7), (0.5, 0.1, -1.1)
    jac_a = _numeric_jacobian(lambda z: compose_scalar(z, b), a)
    jac_b = _numeric_jacobian(lambda z: compose_scalar(a, z), b)
    expected = jac_a @ COV_A @ jac_a.T + jac_b @ COV_B @ jac_b.T
    np.testing.assert_allclose(compose_covariance(COV_A, b, COV_B), expected, atol=1e-12)
    np.testing.assert_allclose(jac_b, np.eye(3), atol=1e-9)  # b's own frame is the result's


def test_inverse_covariance_is_the_first_order_propagation():
    a = (0.3, -0.2, 0.7)
    jac = _numeric_jacobian(inverse_scalar, a)
    np.testing.assert_allclose(inverse_covariance(a, COV_A), jac @ COV_A @ jac.T, atol=1e-12)


# ------------------------------------------------------------------------------------------
# the corridor: exact marginalisation
# ------------------------------------------------------------------------------------------


def corridor() -> tuple[Script, list[int], list[int]]:
    """Lap 1 out along x; back along it 12 s later: relocalised on vertex 18, eight new
    vertices (a revisit run), relocalised on vertex 5."""
    rng = np.random.default_rng(7)
    s = Script(dt=0.5)
    first = [s.create()]
    for _ in range(20):
        s.move(0.2, 0.0, measured=(0.2 * (1 + 0.03 * rng.standard_normal()), 0.0))
        first.append(s.create())
    s.move(0.0, math.pi)
    s.wait(12.0)  # past integration_min_age: lap 1 is known ground
    s.drive(0.4, 2)
    s.relocalise(first[18])
    run = []
    for _ in range(8):
        s.move(0.3, 0.0, measured=(0.3 * (1 + 0.03 * rng.standard_normal()), 0.0))
        run.append(s.create())
    s.move(0.2, 0.0, measured=(0.2 * (1 + 0.03 * rng.standard_normal()), 0.0))
    s.relocalise(first[5])
    return s, first, run


def build(mode: str, script: Script, **params: float) -> CognitiveMap:
    cmap = CognitiveMap(mode, MapParams(**params))
    cmap.apply_all(script.events)
    cmap.finish()
    return cmap


def least_squares_x(graph: PoseGraph) -> dict[int, float]:
    """The exact weighted least-squares x of a graph whose poses lie on the x axis facing 0 or
    pi (y and the headings are then exact and decoupled from x): one linear solve."""
    n = graph.num_vertices
    normal, rhs = np.zeros((n, n)), np.zeros(n)
    heading = np.round(graph.poses[:, 2] / math.pi) * math.pi
    for i, j, z, info in zip(
        graph.edge_from, graph.edge_to, graph.measurements, graph.information, strict=True
    ):
        # residual x: cos(theta_z) (cos(theta_i) (x_j - x_i) - cos(theta_z) z_x) (z_y = 0)
        a = math.cos(z[2]) * math.cos(heading[i])
        w = info[0, 0] * a * a
        normal[i, i] += w
        normal[j, j] += w
        normal[i, j] -= w
        normal[j, i] -= w
        target = z[0] / math.cos(heading[i])
        rhs[j] += w * target
        rhs[i] -= w * target
    fixed = int(np.flatnonzero(graph.fixed)[0])
    normal[fixed], rhs[fixed] = 0.0, graph.poses[fixed, 0]
    normal[fixed, fixed] = 1.0
    return dict(zip(graph.vertex_ids.tolist(), np.linalg.solve(normal, rhs).tolist(), strict=True))


def test_the_corridor_run_is_merged_and_kept_as_one_evidence_edge():
    script, first, run = corridor()
    standard = build("standard", script)
    cmap = build("scene_integration", script)
    assert standard.num_vertices == 29
    assert cmap.snapshot().vertex_ids.tolist() == first
    assert cmap.integrated_vertices == 8
    graph = cmap.graph
    evidence = np.flatnonzero(
        graph.edge_evidence[: graph.num_edges_total] & graph.edge_alive[: graph.num_edges_total]
    )
    assert evidence.size == 1
    k = int(evidence[0])
    assert (graph.edge_from[k], graph.edge_to[k]) == (first[18], first[5])
    assert graph.edge_kind[k] == EdgeKind.LOOP_CLOSURE and graph.edge_held[k]
    # the standard map's chain 18 -> run -> 5, composed with its covariance
    chain = chain_measurement(standard.graph, [first[18], *run, first[5]], LINK_SIGMAS)
    assert chain is not None
    np.testing.assert_allclose(graph.edge_rel[k], chain.relative, atol=1e-12)
    np.testing.assert_allclose(graph.edge_cov[k], chain.covariance, rtol=1e-12)
    # a measurement, not a corridor: optimised, not drawn
    # (lap 1's 20 sequential edges, the link 20 -> 18 that turned the robot round, the evidence)
    assert cmap.num_edges == 22 and len(cmap.snapshot().edge_from) == 21
    pose_graph = cmap.to_pose_graph()
    assert pose_graph.num_edges == 22
    row = int(np.flatnonzero(pose_graph.loop_closure & (pose_graph.edge_to == first[5]))[0])
    np.testing.assert_allclose(
        pose_graph.information[row], 0.03**2 * np.linalg.inv(chain.covariance), rtol=1e-9
    )


def test_marginalising_the_run_leaves_the_standard_maps_estimate_exactly():
    script, first, _ = corridor()
    standard = least_squares_x(build("standard", script).to_pose_graph())
    kept = least_squares_x(build("scene_integration", script).to_pose_graph())
    dropped = least_squares_x(
        build("scene_integration", script, integration_keeps_evidence=0).to_pose_graph()
    )
    assert max(abs(kept[v] - standard[v]) for v in first) < 1e-12
    assert max(abs(dropped[v] - standard[v]) for v in first) > 1e-3  # the paper's merge


def test_the_optimiser_finds_the_same_first_lap_in_both_maps():
    script, first, _ = corridor()
    options = OptimizerOptions(function_tolerance=1e-15, max_iterations=200)
    solved = {}
    for mode in ("standard", "scene_integration"):
        graph = build(mode, script).to_pose_graph()
        poses = optimize_pose_graph(graph, options).poses
        solved[mode] = dict(zip(graph.vertex_ids.tolist(), poses, strict=True))
    worst = max(
        np.max(np.abs(solved["standard"][v] - solved["scene_integration"][v])) for v in first
    )
    assert worst < 1e-8  # Ceres' convergence (measured 7e-10); the exact solve above: 1e-12


# ------------------------------------------------------------------------------------------
# the graph's evidence edges
# ------------------------------------------------------------------------------------------


def three_vertices() -> MapGraph:
    graph = MapGraph()
    for vid, pose in enumerate([(0.0, 0.0, 0.0), (1.0, 0.0, 0.5), (1.0, 1.0, 1.0)]):
        graph.new_id(vid, float(vid), vid)
        graph.add_vertex(vid, pose)
    graph.add_edge(0, 1, (1.0, 0.0, 0.5), 1.0, EdgeKind.SEQUENTIAL, -1)
    return graph


def test_re_attaching_an_evidence_edge_carries_its_covariance_into_the_new_frame():
    graph = three_vertices()
    graph.new_id(3, 3.0, 3)
    graph.add_vertex(3, (1.1, 1.0, 0.8))
    rel = (1.2, 0.9, 1.0)
    k = graph.add_evidence_edge(0, 2, rel, COV_A, 2.0, 0)
    offset = (0.1, -0.05, 0.2)  # vertex 2 in the frame of vertex 3
    graph.merge_vertex(2, 3, offset)
    assert (graph.edge_from[k], graph.edge_to[k]) == (0, 3)
    inv_offset = inverse_scalar(offset)
    jac = _numeric_jacobian(lambda z: compose_scalar(z, inv_offset), rel)
    np.testing.assert_allclose(graph.edge_cov[k], jac @ COV_A @ jac.T, atol=1e-12)
    np.testing.assert_allclose(graph.edge_rel[k], compose_scalar(rel, inv_offset), atol=1e-12)


def test_a_chain_with_a_missing_edge_measures_nothing_and_removal_keeps_no_self_loop():
    graph = three_vertices()
    assert chain_measurement(graph, [0, 1, 2], LINK_SIGMAS) is None
    graph.add_edge(1, 2, (0.0, 1.0, 0.5), 2.0, EdgeKind.LOOP_CLOSURE, 3)
    chain = chain_measurement(graph, [0, 1, 2], LINK_SIGMAS)
    assert chain is not None and chain.edges == (0, 1)
    assert keep_chain_evidence(graph, 0, 0, chain, 3.0) == -1
    assert graph.num_edges == 0


@pytest.mark.parametrize("joined", [False, True])
def test_evidence_is_added_only_between_vertices_not_joined(joined: bool):
    graph = three_vertices()
    graph.add_edge(1, 2, (0.0, 1.0, 0.5), 2.0, EdgeKind.LOOP_CLOSURE, 3)
    if joined:
        graph.add_edge(0, 2, (1.0, 1.0, 1.0), 2.5, EdgeKind.LOOP_CLOSURE, 4)
    chain = chain_measurement(graph, [0, 1, 2], LINK_SIGMAS)
    assert chain is not None
    k = keep_chain_evidence(graph, 0, 2, chain, 3.0)
    if joined:
        assert k == -1 and graph.num_edges == 1  # the existing edge, only
    else:
        assert k == 2 and graph.edge_evidence[k] and graph.edge_cluster[k] == 3
        assert graph.num_edges == 1 and graph.path_edges().tolist() == []
