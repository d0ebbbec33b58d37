"""A merged revisit run's evidence, kept: its chain marginalised onto the vertices it joins.

Beyond the paper. Scene integration (:mod:`cogmap_core.scene_integration`) merges a revisit run
-- vertices made while re-walking known ground, between a relocalisation on ``start`` and one on
``end`` -- into the old vertices, re-attaching the run's edges with the map's current relative
poses. That keeps the map's shape but not what the run measured: an edge whose measurement is
the map's own estimate adds no evidence, so a map that merges its later laps keeps only its
first lap's odometry, while the standard map, which keeps every vertex, averages them all.

What a run measured about the map is its chain ``start -> v1 -> ... -> vk -> end``: its
odometry edges and the loop closure that ended it. Marginalising ``v1 .. vk`` out of that chain
(Carlevaris-Bianco & Eustice's generic linear constraints, for a Markov blanket of two vertices)
leaves one relative-pose constraint between ``start`` and ``end``: the chain's composed
measurement, its covariance propagated to first order (:func:`~cogmap_core.geometry.
compose_covariance`). For a linear-Gaussian chain this is exact: the map's estimate of every
other vertex is the one it would have with the run's vertices kept. The constraint replaces the
run's re-attached edges as an *evidence edge* of the graph (:class:`~cogmap_core.map_graph.
MapGraph`), weighed by its own covariance, held while the merge stands, and not drawn.

The map keeps one edge per vertex pair (OpenRatSLAM's rule): where ``start`` and ``end`` are
already joined, the run's chain is dropped, as the paper drops it. Fusing it into their edge
(information added) was measured and not kept: it broke one of twelve bags, where fused
constraints between neighbouring vertices moved known ground enough that the gate refused the
last lap's relocalisations (``docs/maps.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.edge_noise import OdometryNoise
from cogmap_core.geometry import (
    compose_covariance,
    compose_scalar,
    inverse_covariance,
    inverse_scalar,
)
from cogmap_core.map_graph import MapGraph

FloatArray = NDArray[np.float64]
Pose = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class ChainMeasurement:
    """What a chain of edges measured between its two ends.

    Attributes:
        first: the chain's first vertex.
        relative: the pose of the last vertex in the frame of the first (x, y, theta).
        covariance: its covariance in its own frame (m, rad; first order).
        edges: the edges of the chain, first to last.

    """

    first: int
    relative: Pose
    covariance: FloatArray
    edges: tuple[int, ...]


def chain_measurement(
    graph: MapGraph,
    vertices: Sequence[int],
    link_sigmas: tuple[float, float] | None,
    odometry: OdometryNoise | None = None,
) -> ChainMeasurement | None:
    """The edges joining consecutive ``vertices``, composed; None where two are not joined.

    Each edge weighs as the optimisation weighs it (:meth:`MapGraph.edge_covariances`), read in
    the direction of the chain.
    """
    pairs = list(zip(vertices[:-1], vertices[1:], strict=True))
    edges = [graph.edge_between(a, b) if a != b else -1 for a, b in pairs]
    if min(edges) < 0:
        return None
    relative: Pose = (0.0, 0.0, 0.0)
    covariance = np.zeros((3, 3))
    steps = graph.edge_covariances(np.array(edges), link_sigmas, odometry)
    for (a, _), k, step_cov in zip(pairs, edges, steps, strict=True):
        step: Pose = tuple(graph.edge_rel[k].tolist())  # type: ignore[assignment]
        if int(graph.edge_from[k]) != a:
            step, step_cov = inverse_scalar(step), inverse_covariance(step, step_cov)
        covariance = compose_covariance(covariance, step, step_cov)
        relative = compose_scalar(relative, step)
    return ChainMeasurement(int(vertices[0]), relative, covariance, tuple(edges))


def keep_chain_evidence(
    graph: MapGraph, start: int, end: int, chain: ChainMeasurement, time: float
) -> int:
    """Replace ``chain``'s edges by one evidence edge ``start -> end``; return it (-1: none).

    ``start`` and ``end``: the live vertices the chain's ends are now (after the merges). The
    chain's edges are removed whatever happens; no edge is added when the ends are one vertex
    or already joined (module doc). The new edge joins the closing edge's cluster.
    """
    cluster = int(graph.edge_cluster[chain.edges[-1]])
    for k in chain.edges:
        graph.remove_edge(k)
    if start == end or graph.edge_between(start, end) >= 0:
        return -1
    return graph.add_evidence_edge(start, end, chain.relative, chain.covariance, time, cluster)
