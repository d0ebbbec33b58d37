"""One cluster of loop closures cannot overrule several (after RRR's inter-cluster consistency).

A map optimises once per cluster of loop closures, and its robust loop model
(:mod:`cogmap_core.robust`) keeps the hypothesis of lower robust cost: when new links are
rejected, the hypothesis that they are true and the map only drifted is solved too. A cluster of
false links that agree with each other -- the same look-alike place again and again -- can cost
less accepted than rejected when it arrives: the odometry bends to satisfy it, and links accepted
before it are pushed out (``docs/maps.md``, "Clusters judged against each other":
``parallel_corridors_2``, where 24 structured false links of one pass outweighed 7 true links of
earlier clusters on cost).

Following Latif, Cadena & Neira ("Robust loop closing over time", RSS 2012), the clusters of
links -- a map's time clusters, one optimisation each -- are the units of evidence, judged
against each other: a hypothesis that rejects links the start accepted, from more earlier
clusters than the clusters it accepts links of (the new one, and earlier ones it brings back),
is not taken, whatever its cost. Many links of one pass past one look-alike place are one piece
of evidence; earlier clusters that agree with each other are several. Overruling one earlier
cluster stays a matter of cost: that is how a true return after a long drift displaces the false
link the drift let in.

**Nor can it overrule a merge.** Scene integration merges a revisit run into the places it
re-walked only when the links that bracket the run are ones the loop model keeps
(:mod:`cogmap_core.scene_integration`); the merge then stands for those links, and their
cluster's evidence is in the merged vertices, no longer in links that could be counted as
displaced. A hypothesis that rejects such a link -- accepted at its start -- is not taken either:
on ``parallel_corridors_2`` scene integration, 24 structured false links displaced one link of an
earlier cluster, the link that had opened a merged run, and bent the map by 15 degrees about its
start (2.57 m against 1.13 m from the true links alone; the standard map, which keeps those
revisits as vertices and links, vetoes the same hypothesis for displacing seven links of five
clusters).

RRR's other half, revising an accepted cluster when later ones contradict it, was built and
measured (``docs/maps.md``): once this rule holds it changed no map of 18 generated logs, made one
held-back map worse and extreme-drift logs 1.5-3.5 x slower, so it is not part of the maps.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


def overrules_several(
    clusters: IntArray,
    loops: BoolArray,
    new: BoolArray,
    accepted: BoolArray,
    rejected: BoolArray,
) -> bool:
    """Whether a hypothesis has one cluster overrule several (module doc): it is not taken.

    Args:
        clusters: ``(E,)`` each edge's cluster id (-1 for odometry).
        loops: ``(E,)`` the loop closures.
        new: ``(E,)`` the loop closures added since the last optimisation.
        accepted: ``(E,)`` the earlier loop closures the model accepts at the start.
        rejected: ``(E,)`` the edges the model rejects at the hypothesis' solution.

    """
    displaced = np.unique(clusters[accepted & rejected]).size
    revived = np.unique(clusters[loops & ~new & ~accepted & ~rejected]).size
    return bool(displaced > revived + int((new & ~rejected).any()))


def overrules_a_merge(merged_on: BoolArray, accepted: BoolArray, rejected: BoolArray) -> bool:
    """Whether a hypothesis rejects a link a merge rests on (module doc): it is not taken.

    Args:
        merged_on: ``(E,)`` the loop closures merges rest on (``MapGraph.edge_held``).
        accepted: ``(E,)`` the earlier loop closures the model accepts at the start.
        rejected: ``(E,)`` the edges the model rejects at the hypothesis' solution.

    """
    return bool((merged_on & accepted & rejected).any())


__all__ = ["overrules_a_merge", "overrules_several"]
