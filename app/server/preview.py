"""A map to show at once while an exact rebuild takes long (issue 27, "an answer first").

After a parameter change, a map whose rebuild is slow (its last build took more than
:data:`PREVIEW_AFTER_S`) is first shown as a *preview*, made without replaying the events:

- a change of the cluster schedule only (``t_interval``, ``t_total``): the map shown so far. The
  new schedule only moves when the optimisations run; the events and the vertices are the same.
- a change of the neighborhood field only (``alpha``, ``beta``, ``delta``; the compact map): the
  compact map re-derived from the current *standard* map (:func:`compact_preview`): its live
  vertices walked in creation order, one kept when the field of its pose relative to the last
  kept vertex is novel (:func:`~cogmap_core.neighborhood_fields.is_novel`), the others merged
  into it; the standard map's edges moved onto the kept vertices. Its poses are the standard
  map's optimised ones (no solve); it has no scene integration and no short-edge removal, so it
  usually has more vertices than the exact map.
- any other change: no preview.

A preview is only drawn: the replay keeps it beside the session's maps
(:attr:`app.server.replay.Replay.previews`) until the exact map arrives and never adopts it, so
sessions, exports and the equality with ``cogmap run`` only ever see exact maps. When the exact
map arrives, :func:`preview_difference` says how far the preview was from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.geometry import between_scalar, compose
from cogmap_core.map_graph import EdgeKind
from cogmap_core.neighborhood_fields import is_novel
from cogmap_core.parameter_table import MAP_PARAMETERS, PARAMETERS_USED
from cogmap_core.schedule import SCHEDULE_PARAMS

#: A map whose last build took longer than this (s) is previewed while it is rebuilt (the
#: issue's 200 ms); a map never built before is always previewed.
PREVIEW_AFTER_S = 0.2
#: The neighborhood field's parameters (the paper's that only the compact map uses): a change of
#: only these previews the compact map from the standard map. (A change of only the cluster
#: schedule's, :data:`~cogmap_core.schedule.SCHEDULE_PARAMS`, previews the map shown.)
FIELD_PARAMS = frozenset(
    p.name for p in MAP_PARAMETERS if p.paper and p.maps == frozenset({MapMode.COMPACT})
)


@dataclass(frozen=True)
class Preview:
    """A map shown before its exact rebuild.

    Attributes:
        cmap: what is drawn (never adopted into the session).
        how: ``"schedule"`` (the map shown before; only the cluster schedule changed) or
            ``"fields"`` (the compact map re-derived from the standard map).

    """

    cmap: CognitiveMap
    how: str

    @property
    def description(self) -> str:
        """What the preview is, for the page."""
        if self.how == "schedule":
            return "the map before the new schedule"
        return "neighborhood fields applied to the standard map"


def changed_params(mode: MapMode, old: MapParams, new: MapParams) -> frozenset[str]:
    """The parameters map ``mode`` uses that differ between ``old`` and ``new``."""
    return frozenset(n for n in PARAMETERS_USED[mode] if getattr(old, n) != getattr(new, n))


def make_preview(
    mode: MapMode, current: CognitiveMap, standard: CognitiveMap | None, params: MapParams
) -> Preview | None:
    """The preview of map ``mode`` rebuilt for ``params`` (None: no preview for this change).

    ``current``: the map shown now; ``standard``: the session's standard map (a compact preview
    needs it built for ``params``: the neighborhood field is not among its parameters).
    """
    changed = changed_params(mode, current.params, params)
    if not changed:
        return None
    if changed <= SCHEDULE_PARAMS:
        return Preview(current, "schedule")
    if (
        mode is MapMode.COMPACT
        and changed <= FIELD_PARAMS
        and standard is not None
        and not changed_params(MapMode.STANDARD, standard.params, params)
    ):
        return Preview(compact_preview(standard, params), "fields")
    return None


def compact_preview(standard: CognitiveMap, params: MapParams) -> CognitiveMap:
    """The compact map for ``params`` approximated from ``standard`` (module doc), no solve.

    Every vertex id of ``standard`` is registered: the kept ones live at the standard map's
    poses, the others aliases of the kept vertex they were merged into. Each edge of
    ``standard`` joins the kept vertices its ends were merged into (creation order; an edge
    joining a vertex to itself or two vertices already joined is dropped), its measurement the
    kept vertices' relative pose. The robot stays where the standard map has it; the
    optimisation records are the standard map's (the same schedule ran).
    """
    source = standard.graph
    preview = CognitiveMap(MapMode.COMPACT, params)
    graph = preview.graph
    n = source.num_ids
    for vid in range(n):
        graph.new_id(vid, float(source.vertex_time[vid]), int(source.view[vid]))
    rep = np.full(n, -1, dtype=np.int64)
    alpha, beta, delta = params.alpha, params.beta, params.delta
    last = -1
    last_pose = (0.0, 0.0, 0.0)
    live = source.live_ids()
    for vid, row in zip(live.tolist(), source.pose[live].tolist(), strict=True):
        pose = (row[0], row[1], row[2])
        if last >= 0:
            rel = between_scalar(last_pose, pose)
            if not is_novel(rel, alpha, beta, delta):
                graph.add_alias(vid, last, rel)
                rep[vid] = last
                preview.counters.declined += 1
                continue
        graph.add_vertex(vid, pose)
        rep[vid] = vid
        last, last_pose = vid, pose
    preview.counters.proposed = n
    for vid in np.flatnonzero(rep[:n] < 0).tolist():  # ids the standard map itself merged
        target = rep[int(source.alias[vid])]
        if target >= 0:
            kept = tuple(graph.pose[target].tolist())
            graph.add_alias(vid, int(target), between_scalar(kept, source.pose_of(vid)))
            rep[vid] = target
    edges = source.live_edges()
    ends_a = rep[source.edge_from[edges]]
    ends_b = rep[source.edge_to[edges]]
    for k, a, b in zip(edges.tolist(), ends_a.tolist(), ends_b.tolist(), strict=True):
        if a == b or a < 0 or b < 0 or graph.edge_between(a, b) >= 0:
            continue
        rel = between_scalar(tuple(graph.pose[a].tolist()), tuple(graph.pose[b].tolist()))
        kind = EdgeKind(int(source.edge_kind[k]))
        graph.add_edge(a, b, rel, float(source.edge_time[k]), kind, int(source.edge_cluster[k]))
    current = standard.current_vertex
    if current >= 0 and rep[current] >= 0:
        kept = int(rep[current])
        robot = tuple(standard.current_pose().tolist())
        preview.place_robot(kept, between_scalar(tuple(graph.pose[kept].tolist()), robot))
    preview.optimizations = list(standard.optimizations)
    return preview


def preview_difference(preview: CognitiveMap, exact: CognitiveMap) -> tuple[float, int]:
    """How far ``preview`` was from ``exact``: (largest vertex shift in m, vertex count change).

    The shift: over the exact map's live vertices, the distance (x, y) between the vertex and
    where the preview places the same vertex id (through the vertex it was merged into). The
    count: the preview's live vertices minus the exact map's.
    """
    ids = exact.graph.live_ids()
    g = preview.graph
    ids = ids[ids < g.num_ids]
    target = g.alias[ids]
    known = target >= 0
    ids, target = ids[known], target[known]
    shift = 0.0
    if ids.size:
        placed = compose(g.pose[target], g.alias_offset[ids])
        there = exact.graph.pose[ids]
        shift = float(np.hypot(placed[:, 0] - there[:, 0], placed[:, 1] - there[:, 1]).max())
    return shift, preview.num_vertices - exact.num_vertices
