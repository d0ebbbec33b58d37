"""The live figures (shared): the camera, the network behind the map, the counters, the size chart.

- *Live*: the camera image and its view template (a log: the latest links and their scores),
  what the maps were built with, the counters of the three maps (sizes, where the links and the
  vertex proposals went, accuracy);
- *Network behind the map*: the view template matched and the pose cells, as OpenRatSLAM shows
  them;
- *Map size*: vertices, edges and optimisations over time;
- each viewer's *Clusters & optimisations*: the cluster colours and optimisation log of the map
  it shows (:func:`cluster_log_html`).

Functions here write what they are given into the panel; the page calls them (rate-limited) from
the replay worker's updates, and the accuracy figures come from
:class:`~app.server.figures_worker.FiguresWorker`.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import viser
import viser.uplot
from numpy.typing import NDArray

from app.palette import cluster_color
from app.server.chart import SIZE_SERIES, chart_data, chart_options, chart_series, x_end, y_top
from app.server.figures import LinkJudgement, MapFigures, false_link_label, layout_radius_label
from app.server.network import ACTIVITY_FLOOR, match_text, pose_cell_image, template_image
from app.server.panels import set_content, swatch
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.event_file import KIND_LINK
from cogmap_core.event_log import EventLog
from cogmap_core.frames import EventStep, Frame
from cogmap_core.slam import ALL_MODES

if TYPE_CHECKING:
    from app.server.replay import Replay
    from app.server.replay_state import RebuildRecord
    from app.server.timing import RateLimit

#: How many of a log's latest links the *Live* panel lists.
RECENT_LINKS = 8


@dataclass(frozen=True, slots=True)
class LivePanel:
    """The handles of "Live — shared" and "Network behind the map — shared"."""

    camera_image: viser.GuiImageHandle
    template_md: viser.GuiMarkdownHandle
    links_html: viser.GuiHtmlHandle  # logs: the latest links and their scores
    built_html: viser.GuiHtmlHandle  # what the maps were built with; a rebuild
    counters_html: viser.GuiHtmlHandle
    network_html: viser.GuiHtmlHandle
    template_image: viser.GuiImageHandle
    match_html: viser.GuiHtmlHandle
    pose_cells_image: viser.GuiImageHandle
    pose_cells_html: viser.GuiHtmlHandle


def build_live(gui: viser.GuiApi) -> LivePanel:
    """Add the *Live* and *Network behind the map* folders (empty until the replay runs)."""
    with gui.add_folder("Live — shared"):
        camera_image = gui.add_image(
            np.zeros((60, 104, 3), dtype=np.uint8), label="camera", format="jpeg"
        )
        template_md = gui.add_markdown("view template: –")
        links_html = gui.add_html("")
        built_html = gui.add_html("")
        counters_html = gui.add_html("")

    with gui.add_folder("Network behind the map — shared"):
        network_html = gui.add_html(
            '<div class="cogmap-note" id="cogmap-network">The front end\'s view templates '
            "and pose cells show when the replay runs.</div>"
        )
        template = gui.add_image(
            np.full((20, 60, 3), 255, np.uint8), label="current view · matched template",
            format="png",
        )  # fmt: skip
        match_html = gui.add_html("")
        pose_cells_image = gui.add_image(
            np.full((30, 42, 3), 255, np.uint8), label="pose cells (x, y, θ)", format="jpeg"
        )
        pose_cells_html = gui.add_html("")
    return LivePanel(
        camera_image, template_md, links_html, built_html, counters_html, network_html,
        template, match_html, pose_cells_image, pose_cells_html,
    )  # fmt: skip


def build_size_chart(gui: viser.GuiApi) -> viser.GuiUplotHandle:
    """Add the *Map size* folder: the three maps' sizes and optimisations over time."""
    with gui.add_folder("Map size"):
        return gui.add_uplot(
            tuple(np.zeros(1) for _ in range(len(chart_series()))),
            chart_series(),
            title="vertices (solid), edges (dashed), optimisations (dots)",
            aspect=1.3,
            **chart_options(),  # type: ignore[arg-type]
        )


# ====================================================================== the camera and the network
def camera_rgb(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The camera panel's picture of a frame's image: red, green, blue ``(h, w, 3)``.

    A grey image in its three channels; a colour one (blue, green, red, as a colour camera's
    frames are in OpenRatSLAM's arithmetic) in its own colours.
    """
    rgb = image[:, :, ::-1] if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)
    return np.ascontiguousarray(rgb)


def show_camera(
    panel: LivePanel, frame: Frame, view_template: int | None, index: int, total: int
) -> None:
    """Show frame ``index`` (of ``total``): its image, the view template it matched, its time."""
    for handle in (panel.camera_image, panel.template_image):
        if not handle.visible:  # (hidden while a log was replayed)
            handle.visible = True
    panel.camera_image.image = camera_rgb(frame.image)
    template = "–" if view_template is None else f"#{view_template}"
    panel.template_md.content = (
        f"view template **{template}** · frame {index + 1} / {total} · t = {frame.time:.2f} s"
    )


def show_network(
    panel: LivePanel,
    replay: Replay,
    frame: Frame,
    view_template: int | None,
    index: int,
    pose_cells: RateLimit,
) -> None:
    """The view template panel and the pose cells (as OpenRatSLAM shows them).

    The pose cells are drawn at most as often as ``pose_cells`` allows while playing.
    """
    r = replay
    frontend = r.session.frontend
    local_view = frontend.local_view
    current = local_view.make_template(frame.image)
    matched = None
    if view_template is not None and 0 <= view_template < local_view.count:
        matched = local_view.template(view_template)
    panel.template_image.image = template_image(current, matched)
    k = index - r.base_frames
    error = r.view_errors[k] if 0 <= k < len(r.view_errors) else math.nan
    threshold = frontend.config.vt_match_threshold
    text = match_text(view_template, None if math.isnan(error) else error, threshold,
                      math.isnan(error))  # fmt: skip
    panel.match_html.content = (
        f'<div class="cogmap-note" id="cogmap-match">{html.escape(text)} '
        f"({local_view.count} templates stored)</div>"
    )
    note = (
        '<div class="cogmap-note" id="cogmap-network">Left: the camera image as the local '
        "view cells see it (cropped, resampled, normalised); right: the view template it "
        "matched.</div>"
    )
    set_content(panel.network_html, note)
    processed = r.session.log.frames
    if index + 1 < processed:  # replaying cached events: the front end is further on
        if panel.pose_cells_image.visible:
            panel.pose_cells_image.visible = False
        panel.pose_cells_html.content = (
            '<div class="cogmap-note" id="cogmap-pose-cells">Pose cells: the front end last '
            f"ran at frame {processed}; this frame replays its cached events. They show "
            "again once playback passes that frame.</div>"
        )
        return
    if not pose_cells.due(not r.playing):
        return
    activity = frontend.pose_cell_activity
    peak = frontend.pose_cell_peak
    if not panel.pose_cells_image.visible:
        panel.pose_cells_image.visible = True
    panel.pose_cells_image.image = pose_cell_image(activity, peak)
    n_th = activity.shape[0]
    x, y, th = peak
    panel.pose_cells_html.content = (
        '<div class="cogmap-note" id="cogmap-pose-cells">Activity of the '
        f"{activity.shape[2]} × {activity.shape[1]} × {n_th} pose-cell network at frame "
        f"{index + 1} (dots: cells above {ACTIVITY_FLOOR:.0%} of the peak, larger and "
        f"yellower when stronger); peak (ring) at x {x:.1f}, y {y:.1f}, θ {th:.1f} cells "
        f"({math.degrees(th * 2 * math.pi / n_th):.0f}°).</div>"
    )


def recent_links(log: EventLog, frames: int, count: int) -> list[tuple[float, int, float | None]]:
    """The last ``count`` links of the first ``frames`` frames: (time, target, score), in order.

    Read from the log's columns (the score is None where the link has none).
    """
    end = int(log.frame_end[frames - 1]) if frames else 0
    if count <= 0 or end <= 0:
        return []
    columns = log.columns(end)
    links = np.flatnonzero(columns["kind"] == KIND_LINK)[-count:]
    return [
        (t, r, None if math.isnan(score) else score)
        for t, r, score in zip(
            columns["time"][links].tolist(),
            columns["ref"][links].tolist(),
            columns["score"][links].tolist(),
            strict=True,
        )
    ]


def show_links(panel: LivePanel, replay: Replay, step: EventStep) -> None:
    """Hide the camera panel; list the latest place-recognition links with their scores."""
    for handle in (panel.camera_image, panel.template_image, panel.pose_cells_image):
        if handle.visible:
            handle.visible = False
    note = (
        '<div class="cogmap-note" id="cogmap-network">No camera: this input is a log of '
        "odometry and place recognition, whose links come as they are. There is no front end "
        "here (no view templates, no pose cells); the latest links are under "
        "<i>Live</i>.</div>"
    )
    if panel.network_html.content != note:
        panel.network_html.content = note
        panel.match_html.content = ""
        panel.pose_cells_html.content = ""
    with replay.lock:
        recent = recent_links(replay.session.log, replay.cursor, RECENT_LINKS)
    rows = "".join(
        f"<tr><td>{t:.1f}</td><td>{target}</td><td>{'–' if score is None else f'{score:.3f}'}"
        "</td></tr>"
        for t, target, score in reversed(recent)
    )
    panel.template_md.content = f"step {step.index} · t = {step.time:.2f} s"
    panel.links_html.content = (
        '<div id="cogmap-links" style="font-size:0.85em"><b>place recognition</b>: latest '
        "links (score of each)"
        '<table style="width:100%;font-variant-numeric:tabular-nums">'
        "<tr><th>t (s)</th><th>to vertex</th><th>score</th></tr>"
        + (rows or '<tr><td colspan="3">none yet</td></tr>')
        + "</table></div>"
    )


# ====================================================================== counters
def _share(value: float | None) -> str:
    if value is None or math.isnan(value):
        return "–"
    return f"{value:.3f}"


def figure_texts(cmap: CognitiveMap, figures: MapFigures | None) -> dict[str, str]:
    """A map's figures as the page writes them (``figures``: its accuracy, None before any)."""
    fidelity = None if figures is None else figures.fidelity
    ate = None if figures is None else figures.ate
    false = None if figures is None else figures.false_count
    links = None if figures is None else figures.links
    c = cmap.counters

    def count(value: int | None) -> str:
        return "–" if value is None else str(value)

    return {
        "vertices": str(cmap.num_vertices),
        "edges": str(cmap.num_edges),
        "loops": str(cmap.num_loop_edges),
        "clusters": str(len(cmap.clusters)),
        "optimizations": str(len(cmap.optimizations)),
        "ate": "–" if ate is None else f"{ate:.3f}",
        "completeness": _share(None if fidelity is None else fidelity.completeness),
        "correctness": _share(None if fidelity is None else fidelity.correctness),
        "false": count(false),
        "links": count(None if links is None else links.links),
        "duplicates": count(None if links is None else links.duplicates),
        "refused_links": count(None if links is None else links.refused),
        "made": count(None if links is None else links.made),
        "removed": count(None if links is None else links.removed),
        "proposed": str(c.proposed),
        "declined": str(c.declined),
        "integrated": str(c.integrated),
        "split": str(c.split),
        "short_edges": str(c.short_edges),
        "refused": str(c.refused_relocalisations),
    }


def loop_closures_detected(replay: Replay) -> int:
    """The links the front end detected in the frames replayed so far."""
    log_ = replay.session.log
    k = replay.cursor
    end = log_.frame_end[k - 1] if k else 0
    return int(np.count_nonzero(log_.columns(end)["kind"] == KIND_LINK))


#: The counters' sections: (title, ((key, label), ...)); ``{radius}``: the layout radius.
_SECTIONS: tuple[tuple[str, tuple[tuple[str, str], ...]], ...] = (
    (
        "size",
        (
            ("vertices", "vertices"),
            ("edges", "edges"),
            ("loops", "loop-closure edges"),
            ("clusters", "clusters"),
            ("optimizations", "optimisations"),
        ),
    ),
    (
        "where the links went",
        (
            ("links", "links received"),
            ("duplicates", "duplicates (pair already joined)"),
            ("refused_links", "refused by the relocalisation test"),
            ("made", "loop-closure edges made"),
            ("removed", "… of them merged or removed since"),
        ),
    ),
    (
        "accuracy",
        (
            ("ate", "ATE (m)"),
            ("completeness", "completeness ({radius})"),
            ("correctness", "correctness ({radius})"),
            ("false", "false loop closures in the map"),
        ),
    ),
    (
        "where the proposals went",
        (
            ("proposed", "vertices proposed"),
            ("declined", "declined by neighborhood fields"),
            ("integrated", "merged by scene integration"),
            ("split", "put back: a link their merge rested on was rejected"),
            ("short_edges", "removed as short edges"),
            ("refused", "relocalisations refused"),
        ),
    ),
)


def counters_content(
    replay: Replay, figures: Mapping[MapMode, MapFigures], links: LinkJudgement
) -> str:
    """The counters table of the three maps (with the replay's lock held)."""
    r = replay
    session = r.session
    t = 0.0 if math.isnan(r.frame_time) else r.frame_time
    detected = loop_closures_detected(r)
    false = links.false_before(detected)
    judged = false_link_label(session.evaluation)
    rows = [
        ("time", "time", f"{t:.1f} / {r.duration:.1f} s"),
        ("frames", "frames", f"{r.cursor} / {r.total_frames}"),
        ("loops-detected", "loop closures detected (links)", str(detected)),
        ("loops-false", "… of them false (ground truth)", "–" if false is None else str(false)),
    ]
    n = len(ALL_MODES)
    body = "".join(
        f'<tr><td>{label}</td><td colspan="{n}" id="cogmap-{key}">{value}</td></tr>'
        for key, label, value in rows
    )
    texts = {m: figure_texts(session.maps[m], figures.get(m)) for m in ALL_MODES}
    radius = layout_radius_label(session.evaluation)  # the input kind's
    head = "".join(f"<th>{html.escape(m.value.replace('_', ' '))}</th>" for m in ALL_MODES)
    for title, keys in _SECTIONS:
        body += f'<tr class="cogmap-section"><td colspan="{n + 1}">{title}</td></tr>'
        for key, label in keys:
            cells = "".join(
                f'<td id="cogmap-{m.value}-{key}">{texts[m][key]}</td>' for m in ALL_MODES
            )
            body += f"<tr><td>{label.format(radius=radius)}</td>{cells}</tr>"
    note = (
        '<div class="cogmap-note" id="cogmap-counters-note">A link is false when the ground '
        f"truth puts its two places apart ({html.escape(judged)}). <b>False loop closures "
        "in the map</b>: the map's loop-closure edges made from a link the ground truth "
        "calls false (as in summary.json). Links that join a pair already joined add no "
        "edge (duplicates): on the first lap most links are.</div>"
    )
    return (
        f'<table class="cogmap-table" id="cogmap-counters"><thead><tr><th></th>{head}'
        f"</tr></thead><tbody>{body}</tbody></table>{note}"
    )


# ====================================================================== chart and cluster log
def update_chart(
    server: viser.ViserServer,
    chart: viser.GuiUplotHandle,
    maps: dict[MapMode, CognitiveMap],
    data_time: float,
) -> None:
    """Draw the maps' sizes up to ``data_time`` (session time) into the size chart (at once)."""
    data = chart_data(maps, data_time)
    top = y_top(max(float(np.max(series)) for series in data[SIZE_SERIES]))
    end = x_end(float(data[0][-1]))
    with server.atomic():
        scales = chart_options(top, end)["scales"]
        if chart.scales != scales:
            chart.scales = scales  # type: ignore[assignment]
        chart.data = data
        series = chart_series(maps)
        if tuple(chart.series) != series:
            chart.series = series


def build_cluster_log(gui: viser.GuiApi, folder: viser.GuiFolderHandle) -> viser.GuiHtmlHandle:
    """Add a viewer's cluster log into ``folder`` (:func:`cluster_log_html` fills it)."""
    with folder:
        return gui.add_html("")


def cluster_log_html(mode: MapMode, cmap: CognitiveMap, last: RebuildRecord | None) -> str:
    """The cluster colour legend and the optimisation log of one map (a view's).

    ``last``: the latest parameter change whose maps are all shown (its latency is listed).
    """
    clusters: list[int] = []
    if cmap.num_loop_edges:
        snap = cmap.snapshot()
        loops = snap.edge_cluster[snap.edge_kind == EdgeKind.LOOP_CLOSURE]
        clusters = sorted(set(loops.tolist()))
    swatches = "".join(
        f'<span style="display:inline-block;margin:1px 5px 1px 0">'
        f"{swatch(cluster_color(c))}{c}</span>"
        for c in clusters[-40:]
    )
    legend = (
        f'<div class="cogmap-note" id="cogmap-cluster-legend"><b>{mode.value}</b>: '
        f"loop-closure edges by cluster ({len(clusters)} cluster(s) with edges in the map)"
        f"<br>{swatches or 'none yet'}</div>"
    )
    total = sum(o.wall_s for o in cmap.optimizations)
    summary = (
        f'<div class="cogmap-note"><b>{len(cmap.clusters)}</b> clusters, '
        f"<b>{len(cmap.optimizations)}</b> optimisations ({total:.2f} s in total)</div>"
    )
    sizes = {c.cluster_id: c.edge_count for c in cmap.clusters}
    rows = "".join(
        f"<tr><td>{o.time:.1f}</td><td>{'end' if o.cluster_id < 0 else o.cluster_id}</td>"
        f"<td>{sizes.get(o.cluster_id, 0)}</td><td>{o.vertices}</td><td>{o.iterations}</td>"
        f"<td>{o.wall_s * 1000:.0f}</td><td>{o.integrated}</td>"
        f"<td>{o.short_edges_removed}</td></tr>"
        for o in reversed(cmap.optimizations[-12:])
    )
    table = ""
    if cmap.optimizations:
        table = (
            '<table class="cogmap-table" id="cogmap-optimizations"><thead><tr>'
            "<th>t (s)</th><th>cluster</th><th>links</th><th>V</th><th>iters</th>"
            "<th>ms</th><th>merged</th><th>short</th></tr></thead>"
            f"<tbody>{rows}</tbody></table>"
            '<div class="cogmap-note">links: the loop closures the front end detected in '
            "the cluster (the three maps share one schedule); the map keeps fewer "
            "loop-closure edges (duplicates, refused, merged: see <i>Live</i>).</div>"
        )
    latency = ""
    if last is not None:
        shown = [
            f"{m.value} {last.latency(m) * 1000:.0f} ms ({last.how.get(m, '')})"
            for m in last.published
        ]
        latency = (
            '<div class="cogmap-note" id="cogmap-latency">last parameter change shown '
            f"after: {', '.join(shown)}</div>"
        )
    return legend + summary + table + latency
