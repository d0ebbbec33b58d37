"""Routes on the page: the shortest way between two places clicked in the scene (issue 26).

A viewer clicks *route*, then a start and a goal on a map shown in the scene. The page then
shows, for that viewer only:

- the route on each **shown map** (and on the **standard map**, the reference every compact
  map is compared with): Dijkstra over the map's live edges, weighted by their length in the
  map's current poses, and over joins of its vertices within ``integration_radius``, each place
  snapped to the map's nearest vertex, the way straightened within ``link_sigma_position`` of
  the vertices (:class:`cogmap_core.routes.RouteMap`, with the maps' parameters);
- with ground truth, the **true shortest path** between the two places along the driven
  ground-truth path so far (:func:`cogmap_core.routes.true_path_graph`);
- their lengths side by side, each map's route as a multiple of the true shortest path.

**Frames.** The page draws each map in its own frame (side by side, shifted along x) and the
ground truth aligned to it by the rigid transform of the ATE (``truth -> map``, the one the scene
shows). A click on map ``m`` is a place in ``m``'s frame; the place in the truth's frame is the
inverse alignment of ``m`` applied to it
(:meth:`~cogmap_core.evaluation.RigidTransform2D.inverse`), and in another map ``n``'s frame
``n``'s alignment applied to that. Routes are drawn back the same way, so the standard map's route
and the true path lie over the shown map where the alignments put them. Without ground truth the
maps' frames are taken as one (every map starts at the origin of the same odometry) and there is
no true path.

The computation is split so that the replay never waits for it: :func:`route_inputs` copies what
is needed under the replay's lock (snapshots, alignments, the true path), :func:`plan_routes`
computes without it, on the :class:`RouteWorker`'s thread.
"""

from __future__ import annotations

import html
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from app.palette import GROUND_TRUTH_COLOR, INK, MAP_COLORS, css
from app.server.worker import Worker
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError
from cogmap_core.evaluation import RigidTransform2D
from cogmap_core.map_graph import MapSnapshot, nearest_vertex
from cogmap_core.routes import NoRouteError, Route, RouteMap, true_path_graph

FloatArray = NDArray[np.float64]

#: The true shortest path's colour (the ground truth's), and the casing every route has.
TRUE_ROUTE_COLOR = GROUND_TRUTH_COLOR
ROUTE_CASING = INK
#: Widths (screen pixels, fill and casing) of the three kinds of route drawn on a map: the
#: true shortest path widest, the standard map's route on another map narrower, the map's own
#: narrowest and on top -- where they agree they are drawn one inside the other.
TRUE_WIDTH = (13.0, 17.0)
STANDARD_WIDTH = (7.0, 10.0)
OWN_WIDTH = (3.0, 5.5)
#: Heights above the map (seen from above: the map's own route on top).
ROUTE_Z = 0.013


@dataclass(frozen=True, slots=True)
class Place:
    """A place clicked on map ``mode``: ``xy`` in that map's frame (m)."""

    mode: MapMode
    xy: tuple[float, float]


@dataclass(frozen=True)
class RouteInputs:
    """What routes are computed from, copied out of the replay (:func:`route_inputs`).

    Attributes:
        snapshots: the live part of each map routed on.
        alignments: per map, the rigid transform taking the ground truth onto it (the one the
            scene shows), or None for every map when the frames are taken as one.
        truth: ``(M, 2+)`` the driven ground-truth path so far (truth frame), or None.
        truth_key: what identifies ``truth`` (a cached true-path graph is reused for the same).
        note: why the maps' frames are taken as one, when they are.
        params: the maps' parameters (their join radius and corridor); None: the defaults.

    """

    snapshots: dict[MapMode, MapSnapshot]
    alignments: dict[MapMode, RigidTransform2D] | None
    truth: FloatArray | None
    truth_key: tuple[int, ...] = ()
    note: str = ""
    params: MapParams | None = None


def carry(
    xy: Sequence[float] | FloatArray,
    source: MapMode | None,
    target: MapMode | None,
    alignments: dict[MapMode, RigidTransform2D] | None,
) -> FloatArray:
    """Points ``(K, 2)`` (or one place) from ``source``'s frame to ``target``'s.

    ``None`` is the ground truth's frame. Without alignments every frame is the same.
    """
    points = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if alignments is None or source == target:
        return points.copy()
    if source is not None:
        points = alignments[source].inverse().apply(points)
    if target is not None:
        points = alignments[target].apply(points)
    return points


@dataclass(frozen=True)
class Leg:
    """One route of a plan: a map's (``mode``) or the true shortest path (``mode`` None).

    ``route`` is None when there is none; ``problem`` then says why, in one line.
    """

    mode: MapMode | None
    route: Route | None
    problem: str = ""

    @property
    def name(self) -> str:
        """How the page names it."""
        return "true shortest path" if self.mode is None else f"{self.mode.value} map"

    @property
    def key(self) -> str:
        """Its key in the page's element ids (``cogmap-route-<key>-length``)."""
        return "truth" if self.mode is None else self.mode.value


@dataclass(frozen=True)
class RoutePlan:
    """The routes between two places: one leg per map routed on, and the true shortest path."""

    start: Place
    goal: Place
    legs: tuple[Leg, ...]
    truth: Leg | None
    alignments: dict[MapMode, RigidTransform2D] | None
    note: str = ""

    def leg(self, mode: MapMode | None) -> Leg | None:
        """The leg of map ``mode`` (None: the true shortest path)."""
        if mode is None:
            return self.truth
        return next((leg for leg in self.legs if leg.mode is mode), None)

    def points_on(self, leg: Leg, mode: MapMode) -> FloatArray | None:
        """The route of ``leg`` as drawn on map ``mode``: ``(K, 2)`` in ``mode``'s frame."""
        if leg.route is None:
            return None
        return carry(leg.route.points, leg.mode, mode, self.alignments)

    def place_on(self, place: Place, mode: MapMode) -> FloatArray:
        """A clicked place in map ``mode``'s frame ``(2,)``."""
        return carry(place.xy, place.mode, mode, self.alignments)[0]


def plan_routes(
    inputs: RouteInputs,
    start: Place,
    goal: Place,
    modes: Sequence[MapMode],
    truth_graph: RouteMap | None = None,
) -> RoutePlan:
    """The routes from ``start`` to ``goal`` on the maps ``modes`` and along the true path.

    ``truth_graph`` is :func:`true_path_graph` of ``inputs.truth`` (made here when not given).
    A map the two places cannot be joined on gets its leg's ``problem`` (``no route on the
    standard map: ...``), never an exception.
    """
    alignments = inputs.alignments
    legs = []
    for mode in modes:
        snap = inputs.snapshots[mode]
        a = carry(start.xy, start.mode, mode, alignments)[0]
        b = carry(goal.xy, goal.mode, mode, alignments)[0]
        try:
            route = RouteMap.of(snap, params=inputs.params).route(a, b)
        except NoRouteError as exc:
            legs.append(Leg(mode, None, f"no route on the {mode.value} map: {exc}"))
            continue
        legs.append(Leg(mode, route))
    truth_leg = None
    if inputs.truth is not None and alignments is not None and len(inputs.truth):
        graph = truth_graph if truth_graph is not None else true_path_graph(inputs.truth)
        a = carry(start.xy, start.mode, None, alignments)[0]
        b = carry(goal.xy, goal.mode, None, alignments)[0]
        try:
            truth_leg = Leg(None, graph.route(a, b))
        except NoRouteError as exc:  # (the driven path is one piece: not expected)
            truth_leg = Leg(None, None, f"no true shortest path: {exc}")
    return RoutePlan(start, goal, tuple(legs), truth_leg, alignments, inputs.note)


class TruthGraphs:
    """The true-path graph of the latest truth asked for (building one takes up to a second)."""

    def __init__(self) -> None:
        """Nothing built yet."""
        self._key: tuple[int, ...] | None = None
        self._graph: RouteMap | None = None
        self._lock = threading.Lock()

    def get(self, truth: FloatArray, key: tuple[int, ...]) -> RouteMap:
        """The graph of ``truth`` (built again only when ``key`` changed)."""
        with self._lock:
            if self._key != key or self._graph is None:
                self._graph = true_path_graph(truth)
                self._key = key
            return self._graph


# ====================================================================== the panel
def _metres(value: float) -> str:
    return f"{value:.2f} m"


def message_html(text: str, error: bool = False) -> str:
    """The route panel's one-line message (``#cogmap-route``)."""
    cls = "cogmap-note cogmap-error" if error else "cogmap-note"
    return f'<div class="{cls}" id="cogmap-route">{html.escape(text)}</div>'


def _swatch_line(color: tuple[int, int, int], width: float) -> str:
    return (
        f'<span class="cogmap-swatch" style="background:{css(color)};'
        f"border:1.5px solid {css(ROUTE_CASING)};height:{max(4.0, width * 0.7):.0f}px;"
        'vertical-align:middle"></span>'
    )


def plan_html(plan: RoutePlan, shown: MapMode) -> str:
    """The panel's message and table of a plan, as the viewer of map ``shown`` reads it.

    Element ids: ``cogmap-route`` (the message), ``cogmap-route-lengths`` (the table),
    ``cogmap-route-<key>-length`` and ``cogmap-route-<key>-ratio`` per route (``key``: the map's
    name, or ``truth``).
    """
    problems = [leg.problem for leg in (*plan.legs, plan.truth) if leg is not None and leg.problem]
    start, goal = plan.start.xy, plan.goal.xy
    where = (
        f"from ({start[0]:.2f}, {start[1]:.2f}) to ({goal[0]:.2f}, {goal[1]:.2f}) m on the "
        f"{plan.start.mode.value} map"
    )
    if problems:
        head = message_html(f"route {where}: " + "; ".join(problems), error=True)
    else:
        head = message_html(f"route {where}")
    truth = plan.truth.route if plan.truth is not None else None
    reference = truth.length if truth is not None else None
    rows = []
    legs = [*plan.legs] + ([plan.truth] if plan.truth is not None else [])
    for leg in legs:
        if leg.mode is None:
            swatch = _swatch_line(TRUE_ROUTE_COLOR, TRUE_WIDTH[0])
            label = "true shortest path"
        else:
            width = OWN_WIDTH[0] if leg.mode is shown else STANDARD_WIDTH[0]
            swatch = _swatch_line(MAP_COLORS[leg.mode], width)
            label = leg.mode.value.replace("_", " ") + (" (shown)" if leg.mode is shown else "")
        route = leg.route
        if route is None:
            length = ratio = edges = gap = "–"
        else:
            length = _metres(route.length)
            if reference is None:
                ratio = "–"
            elif reference > 0:
                ratio = f"{route.length / reference:.3f}"
            else:
                ratio = "1.000" if route.length == 0 else "–"
            edges = str(route.num_edges) if leg.mode is not None else "–"
            gap = f"{route.start_gap:.2f} / {route.goal_gap:.2f}"
        rows.append(
            f"<tr><td>{swatch}{html.escape(label)}</td>"
            f'<td id="cogmap-route-{leg.key}-length">{length}</td>'
            f'<td id="cogmap-route-{leg.key}-ratio">{ratio}</td>'
            f"<td>{edges}</td><td>{gap}</td></tr>"
        )
    table = (
        '<table class="cogmap-table" id="cogmap-route-lengths"><thead><tr><th>route</th>'
        "<th>length</th><th>÷ true</th><th>edges</th><th>snap (m)</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )
    if truth is not None:
        how = (
            "÷ true: each route's length over the true shortest path along the driven "
            "ground-truth path (its samples joined where they pass within 5 cm). Places are "
            "carried between the maps and the truth by the alignments the scene shows."
        )
    else:
        how = plan.note or "No ground truth: the maps' frames are taken as one."
    note = (
        f'<div class="cogmap-note" id="cogmap-route-note">{html.escape(how)} snap: how far the '
        "start / goal lie from the vertex each was snapped to. Edge lengths are the distances "
        "between their ends' current (optimised) poses; vertices within the map's integration "
        "radius are joined (edges counts the joins taken), and each way is straightened within "
        "the map's link sigma (position) of its vertices.</div>"
    )
    return head + table + note


# ====================================================================== the worker
T = TypeVar("T")


class RouteWorker(Worker[T]):
    """One thread that computes routes: callbacks only flag who needs one (latest wins).

    ``work(item)`` runs on the thread for each item flagged; an item flagged again while its
    work runs is done once more afterwards. An exception is printed and never stops the thread
    (:class:`~app.server.worker.Worker`).
    """

    def __init__(self, work: Callable[[T], None], name: str = "cogmap-routes") -> None:
        """Start the thread."""
        super().__init__()
        self._work = work
        self._todo: dict[int, T] = {}
        self._start(name)

    def request(self, item: T) -> None:
        """Flag ``item`` for work."""
        with self._cond:
            self._todo[id(item)] = item
            self._cond.notify()

    def _pending(self) -> bool:
        return bool(self._todo)

    def _take(self) -> T:
        """One item flagged (the one flagged last; each flags once until taken)."""
        _, item = self._todo.popitem()
        return item

    def _work_on(self, work: T) -> None:
        self._work(work)


def route_inputs(
    snapshots: dict[MapMode, MapSnapshot],
    transforms: dict[MapMode, tuple[float, float, float] | None],
    truth: FloatArray | None,
    truth_key: tuple[int, ...],
    params: MapParams | None = None,
) -> RouteInputs:
    """Inputs of :func:`plan_routes` from the scene's alignments ``(theta, tx, ty)`` per map.

    The truth is used only when every map routed on has its alignment (the figures compute
    them about once a second); otherwise the frames are taken as one, and the note says why.
    ``params``: the maps' parameters (None: the defaults).
    """
    if truth is None or not len(truth):
        return RouteInputs(
            snapshots,
            None,
            None,
            (),
            "No ground truth: the maps' frames are taken as one.",
            params,
        )
    if any(transforms.get(mode) is None for mode in snapshots):
        return RouteInputs(
            snapshots,
            None,
            None,
            (),
            "The maps' alignments to the ground truth are not computed yet (they follow within "
            "a second): the maps' frames are taken as one, without the true path.",
            params,
        )
    alignments = {
        mode: RigidTransform2D(*transform)  # type: ignore[misc]
        for mode, transform in transforms.items()
        if transform is not None and mode in snapshots
    }
    return RouteInputs(snapshots, alignments, truth, truth_key, params=params)


def nearest_map(
    point: FloatArray, offsets: dict[MapMode, float], snapshots: dict[MapMode, MapSnapshot]
) -> Place | None:
    """The place a click at scene point ``point`` names: on the shown map with the nearest vertex.

    ``offsets``: each shown map's shift along x in the scene. None when no map has a vertex.
    """
    best: tuple[float, Place] | None = None
    for mode, offset in offsets.items():
        local = (float(point[0]) - offset, float(point[1]))
        found = nearest_vertex(snapshots[mode].poses, local)
        if found is None:
            continue
        d = found[1]
        if best is None or d < best[0]:
            best = (d, Place(mode, local))
    return None if best is None else best[1]


def route_problem(exc: Exception) -> str:
    """One line for the page about a route that could not be computed."""
    if isinstance(exc, CogmapError):
        return str(exc)
    return f"the route could not be computed ({type(exc).__name__})"


__all__ = [
    "OWN_WIDTH",
    "ROUTE_CASING",
    "ROUTE_Z",
    "STANDARD_WIDTH",
    "TRUE_ROUTE_COLOR",
    "TRUE_WIDTH",
    "Leg",
    "Place",
    "RouteInputs",
    "RoutePlan",
    "RouteWorker",
    "TruthGraphs",
    "carry",
    "message_html",
    "nearest_map",
    "plan_html",
    "plan_routes",
    "route_inputs",
    "route_problem",
]
