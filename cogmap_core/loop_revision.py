"""Revising loop-closure decisions as evidence accumulates (RRR-style inter-cluster consistency).

A map optimises once per cluster of loop closures, and its robust loop model
(:mod:`cogmap_core.robust`) keeps the hypothesis of lower robust cost. A cluster of false links
that agree with each other -- the same look-alike place again and again -- can cost less
accepted than rejected when it arrives: the odometry bends to satisfy it, and links accepted
before it are pushed out. Later returns show the bend for what it is, but iteratively
reweighted least squares only moves downhill from where the map is, so the decision would
stay frozen.

Following Latif, Cadena & Neira ("Robust loop closing over time", RSS 2012), the clusters of
links -- a map's time clusters, one optimisation each -- are the units of evidence, judged
against each other (:func:`~cogmap_core.optimizer.optimize_pose_graph`):

- **One cluster cannot overrule several.** A hypothesis that accepts new links by rejecting
  links of more than one earlier cluster that the map accepted is not taken, whatever its
  cost (the map's ``clusters``): many links of one pass past one look-alike place are one
  piece of evidence, not many, while earlier clusters that agree with each other are
  independent ones. Overruling one earlier cluster stays a matter of cost: that is how a
  true return after a long drift displaces the false link the drift let in.
- **A decision can be revised.** A cluster is *contested* when the optimisation that
  accepted it rejected links that were accepted before it. The map remembers its contested
  clusters (:class:`ContestedClusters`); whenever a later optimisation rejects some of its
  own new links, each contested cluster it still accepts is tested once more: the
  hypothesis that the cluster is false and the new links are true is solved from the same
  start (``suspects``), and the solution of lower robust cost is kept.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


class ContestedClusters:
    """The clusters of loop closures whose acceptance displaced earlier links (module doc).

    Each is kept as the map graph's ids of its loop-closure edges (those it accepted).
    """

    def __init__(self) -> None:
        """No contested cluster yet."""
        self.groups: list[IntArray] = []

    def suspects(self, live_edges: IntArray) -> list[BoolArray]:
        """Per contested cluster, which of the live edges (graph order) are its links."""
        masks = [np.isin(live_edges, group) for group in self.groups]
        return [mask for mask in masks if mask.any()]

    def note(
        self,
        live_edges: IntArray,
        new: BoolArray,
        accepted_before: BoolArray,
        rejected_after: BoolArray,
    ) -> bool:
        """Record the new links as contested when accepting them displaced earlier links.

        Args:
            live_edges: the map graph's ids of the optimised graph's edges.
            new: ``(E,)`` loop closures added since the last optimisation.
            accepted_before: ``(E,)`` earlier loop closures the model accepted at the start.
            rejected_after: ``(E,)`` loop closures the model rejects at the solution.

        Returns:
            Whether a contested cluster was recorded.

        """
        accepted_new = new & ~rejected_after
        displaced = accepted_before & rejected_after
        if not (accepted_new.any() and displaced.any()):
            return False
        self.groups.append(live_edges[accepted_new].astype(np.int64))
        return True

    def state_dict(self) -> list[list[int]]:
        """The contested clusters' edge ids, as lists."""
        return [group.tolist() for group in self.groups]

    def load_state(self, state: list[Any]) -> None:
        """Become the record :meth:`state_dict` described."""
        self.groups = [np.asarray(group, dtype=np.int64) for group in state]
