"""What a change of the clustering thresholds does to a map (the rebuilds' shortcuts).

``T_interval`` and ``T_total`` act on a map only through the schedule of loop-closure clusters
(:func:`~cogmap_core.clustering.cluster_schedule`: which links form a cluster, at which event it
closes and the map is optimised). When that schedule over the events so far is the same for the
old and the new values, the map is the same and is kept (:func:`same_schedule`); otherwise the
maps agree up to where the schedules part (:func:`schedule_divergence`), from where a build
resumes (:func:`schedule_shared`, the rule :func:`cogmap_core.map_build.build_map` follows).
"""

from __future__ import annotations

import numpy as np

from cogmap_core.clustering import cluster_schedule
from cogmap_core.config import MapParams
from cogmap_core.event_file import KIND_LINK
from cogmap_core.event_log import EventLog
from cogmap_core.parameter_table import CLUSTERING_PARAMETERS

#: The parameters of the loop-closure clustering (the cluster schedule): the parameter table's
#: (:data:`~cogmap_core.parameter_table.CLUSTERING_PARAMETERS`).
SCHEDULE_PARAMS: frozenset[str] = CLUSTERING_PARAMETERS


def same_schedule(
    log: EventLog,
    frames: int,
    finish: bool,
    old: MapParams,
    new: MapParams,
) -> bool:
    """Whether a map built with ``old`` is exactly the map built with ``new`` (module doc).

    True only when the two differ in nothing but ``t_interval``/``t_total`` and those give the same
    cluster schedule over the first ``frames`` frames.
    """
    changed = _changed(old, new)
    if not changed or not changed <= SCHEDULE_PARAMS:
        return not changed
    end = int(log.frame_end[frames - 1]) if frames else 0
    columns = log.columns(end)
    times, links = columns["time"], np.flatnonzero(columns["kind"] == KIND_LINK)
    return cluster_schedule(times, links, end, finish, old.t_interval, old.t_total) == (
        cluster_schedule(times, links, end, finish, new.t_interval, new.t_total)
    )


def schedule_divergence(log: EventLog, end: int, old: MapParams, new: MapParams) -> int:
    """How many of the first ``end`` events maps built with ``old`` and ``new`` apply alike.

    For parameters that differ only in ``t_interval``/``t_total``: the clusters before the first
    one whose (first link, last link, close) differs are the same, and that cluster starts at
    the same link in both schedules; the maps are the same until the earlier of its two closes
    (where one of them is optimised). ``end`` when the schedules agree throughout.
    """
    columns = log.columns(end)
    times, links = columns["time"], np.flatnonzero(columns["kind"] == KIND_LINK)
    a = cluster_schedule(times, links, end, False, old.t_interval, old.t_total)
    b = cluster_schedule(times, links, end, False, new.t_interval, new.t_total)
    for c in range(min(len(a), len(b))):
        if a[c] != b[c]:
            return min(end if a[c][2] < 0 else a[c][2], end if b[c][2] < 0 else b[c][2])
    if len(a) != len(b):  # (cannot happen over the same links; be safe: its first link)
        return (a if len(a) > len(b) else b)[min(len(a), len(b))][0]
    return end


def schedule_shared(log: EventLog, end: int, old: MapParams, new: MapParams) -> int | None:
    """How many of the first ``end`` events maps built with ``old`` and ``new`` apply alike.

    The builds' :data:`~cogmap_core.map_build.Divergence` rule: for parameters that differ only
    in ``T_interval`` and ``T_total``, the maps agree up to where the schedules part
    (:func:`schedule_divergence`); any other change is no start at all (None).
    """
    changed = _changed(old, new)
    if not changed <= SCHEDULE_PARAMS:
        return None
    return schedule_divergence(log, end, old, new)


def _changed(old: MapParams, new: MapParams) -> set[str]:
    """The names of the parameters that differ."""
    return {k for k, v in old.to_dict().items() if getattr(new, k) != v}


__all__ = ["SCHEDULE_PARAMS", "same_schedule", "schedule_divergence", "schedule_shared"]
