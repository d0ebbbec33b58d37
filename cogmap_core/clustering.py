"""Loop-closure clustering by time (paper, section "Clustering Loop Closure Edges").

Loop-closure edges are grouped incrementally. The first edge opens a cluster at its time
``t_start``. A later edge at time ``t`` joins the open cluster when it comes less than
``T_interval`` after the previous loop-closure edge (``t - t_prev < T_interval``) and no more than
``T_total`` after the cluster's first edge (``t - t_start <= T_total``); otherwise it opens a new
cluster. A cluster is *closed* -- and the map optimised once -- as soon as data time shows that no
further edge can join it: at the first event with ``t - t_prev >= T_interval`` or
``t - t_start > T_total``, and at the end of the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


def joins(
    start_time: float, last_time: float, time: float, t_interval: float, t_total: float
) -> bool:
    """The clustering rule: whether an edge at ``time`` joins the cluster opened at ``start_time``.

    True when the edge comes less than ``t_interval`` after the cluster's latest edge (at
    ``last_time``) and no more than ``t_total`` after its first. When it is false for an event
    at ``time``, the cluster is closed. This is the rule's one definition: the map's clusterer,
    the map's fast odometry path, the rebuild planner's schedule and the compiled replay (which
    compiles this very function) all call it. Plain arithmetic on floats, so numba compiles it.
    """
    return time - last_time < t_interval and time - start_time <= t_total


@dataclass(slots=True)
class Cluster:
    """One cluster of loop-closure edges.

    Attributes:
        cluster_id: 0, 1, 2, ... in creation order.
        start_time: time of the first edge.
        last_time: time of the latest edge.
        edge_count: number of loop-closure edges in the cluster.
        closed_time: data time at which the cluster was closed (None while open).

    """

    cluster_id: int
    start_time: float
    last_time: float
    edge_count: int = 1
    closed_time: float | None = None


@dataclass(slots=True)
class LoopClosureClusterer:
    """Incremental time-based clustering of loop-closure edges.

    Use :meth:`due` before handling an event at time ``t`` (it closes the open cluster if no edge
    can join it any more) and :meth:`add_edge` for each loop-closure edge.
    """

    t_interval: float
    t_total: float
    clusters: list[Cluster] = field(default_factory=list)
    _open: Cluster | None = None

    @property
    def open_cluster(self) -> Cluster | None:
        """The cluster still accepting edges, if any."""
        return self._open

    def _accepts(self, cluster: Cluster, time: float) -> bool:
        return joins(cluster.start_time, cluster.last_time, time, self.t_interval, self.t_total)

    def due(self, time: float) -> Cluster | None:
        """Close and return the open cluster if an edge at ``time`` could no longer join it."""
        cluster = self._open
        if cluster is not None and not self._accepts(cluster, time):
            cluster.closed_time = time
            self._open = None
            return cluster
        return None

    def add_edge(self, time: float) -> tuple[int, Cluster | None]:
        """Assign a loop-closure edge at ``time`` to a cluster.

        Returns:
            The cluster id of the edge, and the cluster this edge caused to close (if any).

        """
        closed = self.due(time)
        cluster = self._open
        if cluster is None:
            cluster = Cluster(cluster_id=len(self.clusters), start_time=time, last_time=time)
            self.clusters.append(cluster)
            self._open = cluster
        else:
            cluster.last_time = time
            cluster.edge_count += 1
        return cluster.cluster_id, closed

    def finish(self, time: float) -> Cluster | None:
        """Close the open cluster at the end of the data."""
        cluster = self._open
        if cluster is not None:
            cluster.closed_time = time
            self._open = None
        return cluster

    def state_dict(self) -> dict[str, Any]:
        """The clusters as plain data, what :meth:`load_state` restores.

        ``clusters``: per cluster (in id order) its ``start_time``, ``last_time``,
        ``edge_count`` and ``closed_time`` (None while open); ``open``: whether the newest one
        is still open. ``t_interval`` and ``t_total`` are settings (the map's parameters), not
        state.

        Raises:
            ValueError: the open cluster is not the newest one (it always is).

        """
        if self._open is not None and (not self.clusters or self.clusters[-1] is not self._open):
            raise ValueError("the open cluster is not the newest one; cannot save the clusterer")
        clusters = [
            {
                "start_time": c.start_time,
                "last_time": c.last_time,
                "edge_count": c.edge_count,
                "closed_time": c.closed_time,
            }
            for c in self.clusters
        ]
        return {"clusters": clusters, "open": self._open is not None}

    def load_state(self, state: dict[str, Any]) -> None:
        """Hold the clusters :meth:`state_dict` described (the thresholds stay as they are)."""
        self.clusters = [
            Cluster(k, c["start_time"], c["last_time"], c["edge_count"], c["closed_time"])
            for k, c in enumerate(state["clusters"])
        ]
        self._open = self.clusters[-1] if state["open"] else None


def cluster_schedule(
    times: NDArray[np.float64],
    link_index: NDArray[np.int64],
    end: int,
    finish: bool,
    t_interval: float,
    t_total: float,
) -> tuple[tuple[int, int, int], ...]:
    """The loop-closure cluster schedule of ``events[:end]``, as a map's clusterer makes it.

    ``times`` are the data times of all events, ``link_index`` the positions of the links among
    them (ascending). Returns, per cluster, (its first link's event index, its last link's event
    index, the index of the event at which it closes -- ``end`` when it closes at the end of the
    data, -1 when it is still open). Two parameter sets with the same schedule build the same
    map when they differ only in ``t_interval`` and ``t_total``
    (the rule of :func:`joins`, which :class:`LoopClosureClusterer` applies).
    """
    links = link_index[link_index < end]
    if links.size == 0:
        return ()
    t_links = times[links].tolist()
    starts = [0]
    start = last = t_links[0]
    for i in range(1, len(t_links)):
        t = t_links[i]
        if joins(start, last, t, t_interval, t_total):
            last = t
        else:
            starts.append(i)
            start = last = t
    bounds = starts + [len(t_links)]
    index = links.tolist()
    out: list[tuple[int, int, int]] = []
    for c in range(len(starts)):
        first, last_link = index[bounds[c]], index[bounds[c + 1] - 1]
        t_start, t_last = float(times[first]), float(times[last_link])
        close = _first_closing(times, last_link + 1, end, t_start, t_last, t_interval, t_total)
        if close >= end:
            close = end if finish else -1
        out.append((first, last_link, close))
    return tuple(out)


def _first_closing(
    times: NDArray[np.float64],
    lo: int,
    hi: int,
    t_start: float,
    t_last: float,
    t_interval: float,
    t_total: float,
) -> int:
    """The first index in ``[lo, hi)`` whose time closes the cluster (``hi`` when there is none).

    The clustering rule (:func:`joins`) evaluated as the clusterer does;
    times do not decrease, so "no longer joins" is monotonic and a binary search finds it.
    """
    while lo < hi:
        mid = (lo + hi) // 2
        if joins(t_start, t_last, float(times[mid]), t_interval, t_total):
            lo = mid + 1
        else:
            hi = mid
    return lo
