"""Exports of the web app: map as g2o, summary.json, sizes.csv, a self-contained HTML replay.

The summary and sizes are those of ``cogmap run`` (:func:`app.summary.session_summary`,
:func:`app.summary.write_sizes_csv`) for the frames replayed so far. The HTML replay is made by
replaying the cached front-end events into fresh maps on a private viser server whose scene
serializer records the incremental updates (with pauses between key frames); the resulting page
plays the map growing, with optimisations, with no server behind it.
"""

from __future__ import annotations

import contextlib
import copy
import html
import io
import json
import math
import os
import re
import socket
import stat
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from app.server.access import AccessPolicy, guarded_server
from app.server.assets import read_asset
from app.server.figures import judge_links, map_false_edges, truth_transform
from app.server.files import REPLAY_MARKER, is_cogmap_replay
from app.server.scene import MapExtras, SceneStreamer
from app.server.view import PLAN_FOV
from app.summary import read_warnings, session_summary, source_description, write_sizes_csv
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import InputFileError
from cogmap_core.evaluation import EvaluationSettings
from cogmap_core.event_log import EventLog
from cogmap_core.events import MapEvent, Odometry
from cogmap_core.fileio import check_writable, output_error, write_text_atomic
from cogmap_core.g2o import format_g2o
from cogmap_core.slam import SlamSession

if TYPE_CHECKING:
    from app.server.replay import Replay

#: Key frames of an HTML replay and its playing time.
REPLAY_KEYFRAMES = 240
REPLAY_SECONDS = 40.0


def default_replay_name(mode: MapMode) -> str:
    """The name "save HTML replay" proposes: ``cogmap-replay-<map>.html`` (in the export folder)."""
    return f"cogmap-replay-{mode.value}.html"


def g2o_bytes(cmap: CognitiveMap) -> bytes:
    """The map as g2o text (``VERTEX_SE2``, ``FIX``, ``EDGE_SE2``)."""
    return "".join(format_g2o(cmap.to_pose_graph())).encode()


def view_session(replay: Replay) -> SlamSession:
    """A frozen copy of the replay's current maps and of the log up to its current frame.

    Call with ``replay.lock`` held; the copy can then be read without it while the replay goes on
    (copying takes ~6 ms for the default dataset's three maps, the summary's figures ~150 ms).
    """
    source = replay.session
    view = SlamSession(
        source.params, replay.frontend_config, source.modes, evaluation=source.evaluation
    )
    view.log = source.log.truncated(replay.cursor)
    view.maps.maps = {mode: copy.deepcopy(cmap) for mode, cmap in source.maps.maps.items()}
    view.finished = replay.at_end
    return view


@dataclass(frozen=True, slots=True)
class SummaryInputs:
    """What ``summary.json`` is computed from, copied from a replay (:func:`summary_inputs`)."""

    session: SlamSession
    dataset: str
    first: float
    last: float
    processing_s: float
    warnings: dict[str, object]
    source: dict[str, object]


def summary_inputs(replay: Replay) -> SummaryInputs:
    """Copy what ``summary.json`` needs from ``replay`` (call with ``replay.lock`` held)."""
    view = view_session(replay)
    times = view.log.frame_time
    warnings: dict[str, object] = {}
    source: dict[str, object] = {}
    if replay.reader is not None:
        warnings = read_warnings(replay.reader)
        source = source_description(replay.reader)
    return SummaryInputs(
        session=view,
        dataset=str(replay.bag_path) if replay.bag_path is not None else "",
        first=float(times[0]) if len(times) else 0.0,
        last=float(times[-1]) if len(times) else 0.0,
        processing_s=replay.processing_s,
        warnings=warnings,
        source=source,
    )


def summary_dict(inputs: SummaryInputs) -> dict[str, object]:
    """``summary.json`` of the frames replayed so far (no lock needed: ``inputs`` is a copy)."""
    return session_summary(
        inputs.session,
        inputs.dataset,
        inputs.first,
        inputs.last,
        inputs.processing_s,
        inputs.warnings,
        source=inputs.source,
    )


def summary_bytes(inputs: SummaryInputs) -> bytes:
    """``summary.json`` as bytes (no lock needed: ``inputs`` is a copy)."""
    return (json.dumps(summary_dict(inputs), indent=2) + "\n").encode()


def sizes_csv_bytes(replay: Replay) -> bytes:
    """``sizes.csv`` of the current maps (call with ``replay.lock`` held)."""
    handle = io.StringIO(newline="")
    write_sizes_csv(replay.session.maps.maps, handle)
    return handle.getvalue().encode()


# ---------------------------------------------------------------------------------- HTML replay
def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _dead_reckoning_extent(events: Sequence[MapEvent]) -> tuple[float, float, float, float]:
    """Bounding box of the odometry path (where the maps will be, before corrections)."""
    odo = [(e.translation, e.rotation) for e in events if isinstance(e, Odometry)]
    if not odo:
        return (-1.0, 1.0, -1.0, 1.0)
    arr = np.asarray(odo)
    heading = np.cumsum(arr[:, 1])
    x = np.cumsum(arr[:, 0] * np.cos(heading))
    y = np.cumsum(arr[:, 0] * np.sin(heading))
    return float(x.min()), float(x.max()), float(y.min()), float(y.max())


def _quiet() -> contextlib.ExitStack:
    """Silence viser: a banner when a server starts, "(viser) Server stopped" when it stops."""
    stack = contextlib.ExitStack()
    stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
    stack.enter_context(contextlib.redirect_stderr(io.StringIO()))
    return stack


def replay_caption(
    modes: Sequence[MapMode],
    params: MapParams,
    bag: str,
    seconds: float,
    replay_s: float,
    static_dir: Path | None = None,
) -> str:
    """The caption of an exported replay (``static/replay-caption.html`` filled in)."""
    template = read_asset("replay-caption.html", static_dir)
    if not template:
        return ""
    values = (
        f"α {params.alpha:g} · β {params.beta:g} · δ {params.delta:g} · "
        f"T_interval {params.t_interval:g} s · T_total {params.t_total:g} s"
    )
    return template.format(
        maps=html.escape(" beside ".join(f"{m.value} map" for m in modes)),
        bag=html.escape(bag),
        params=html.escape(values),
        seconds=f"{seconds:.0f}",
        replay_s=f"{replay_s:.0f}",
    )


def with_caption(page: str, caption: str, title: str) -> str:
    """``page`` (viser's HTML) titled ``title``, with ``caption`` at the start of its body.

    The head starts with :data:`~app.server.files.REPLAY_MARKER`: a file that does not is not
    one of ours, and is never replaced.
    """
    page = re.sub(r"(<head[^>]*>)", lambda m: m.group(1) + REPLAY_MARKER, page, count=1)
    page = re.sub(r"<title>.*?</title>", f"<title>{html.escape(title)}</title>", page, count=1)
    if caption:
        page = re.sub(r"(<body[^>]*>)", lambda m: m.group(1) + caption, page, count=1)
    return page


def html_replay(
    log: EventLog,
    params: MapParams,
    modes: Sequence[MapMode],
    finish: bool,
    keyframes: int = REPLAY_KEYFRAMES,
    seconds: float = REPLAY_SECONDS,
    bag: str = "",
    static_dir: Path | None = None,
    judging: EvaluationSettings | None = None,
) -> str:
    """A self-contained HTML page replaying the maps ``modes`` built from ``log``.

    The events are applied to fresh maps with ``params``; after every key frame the scene is
    updated incrementally on a private viser server, whose serializer records it with a pause,
    so that the whole session plays in about ``seconds``. The ground truth is aligned to each
    map as on the page, and the false loop closures are marked with the page's tolerances
    (``judging``, the input kind's; default a bag's); a caption names the maps, the bag and the
    parameters.
    """
    modes = tuple(modes)
    with _quiet():  # (guarded as the page's server is: no other origin reads the scene)
        server = guarded_server("127.0.0.1", _free_port(), AccessPolicy(), label=None, quiet=True)
    try:
        streamer = SceneStreamer(server, modes)
        streamer.show(modes)
        streamer.min_span = 40.0 * (judging or EvaluationSettings()).layout_radius
        x0, x1, y0, y1 = _dead_reckoning_extent(log.events)
        span = max(x1 - x0, y1 - y0, 1.0) * (len(modes) + 1) / 2
        cx, cy = (x0 + x1) / 2 + (len(modes) - 1) * (x1 - x0 + 0.5) / 2, (y0 + y1) / 2
        # the plan view, as on the page: straight down, north up, a narrow field of view
        distance = 1.3 * span / (2.0 * math.tan(PLAN_FOV / 2.0))
        server.initial_camera.fov = PLAN_FOV
        server.initial_camera.near = 0.2 * distance
        server.initial_camera.far = 5.0 * distance
        server.initial_camera.position = (cx, cy - 1e-4 * distance, distance)
        server.initial_camera.look_at = (cx, cy, 0.0)
        serializer = server.get_scene_serializer()
        maps = {m: CognitiveMap(m, params) for m in modes}
        n = log.frames
        step = max(1, math.ceil(n / max(1, keyframes)))
        pause = seconds / max(1, math.ceil(n / step))
        truth = log.ground_truth if log.has_ground_truth() else None
        links = judge_links(log, judging)
        done = 0
        for k in range(step, n + step, step):
            k = min(k, n)
            end = log.frame_end[k - 1]
            for cmap in maps.values():
                cmap.apply_all(log.events[done:end])
            done = end
            if k == n and finish:
                for cmap in maps.values():
                    cmap.finish(log.frame_time[-1])
            extras = {
                m: MapExtras(truth_transform(log, c), map_false_edges(c, links))
                for m, c in maps.items()
            }
            streamer.publish(maps, truth, k, extras, duration=log.frame_time[-1])
            serializer.insert_sleep(pause)
        duration = log.frame_time[-1] - log.frame_time[0] if n else 0.0
        caption = replay_caption(modes, params, bag, duration, seconds, static_dir)
        return with_caption(serializer.as_html(), caption, f"cogmap replay · {bag}")
    finally:
        with _quiet():
            server.stop()


def save_html_replay(
    replay: Replay,
    modes: Sequence[MapMode],
    path: Path,
    keyframes: int = REPLAY_KEYFRAMES,
    seconds: float = REPLAY_SECONDS,
    static_dir: Path | None = None,
    sent: Callable[[bytes], None] | None = None,
) -> Path:
    """Write the HTML replay of ``replay`` up to its current frame to ``path`` (atomically).

    ``path`` is the server's choice (the page's: :class:`~app.server.files.ExportFolder`). The
    folder is checked writable before the page is rendered; the file gets the user's normal
    permissions, and a failed write leaves an existing file as it was. A file in the way is
    replaced only if it is a regular file starting like a cogmap replay (its first 64 kB are
    read, never more). ``sent`` receives the page written (to send it to a browser).

    Raises:
        InputFileError: ``path`` does not end in ``.html``, or is something else than a replay.
        OutputError: the folder cannot be made or written, or the disk is full.

    """
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputFileError(f"{path}: an HTML replay must be saved as a .html file")
    try:
        existing = os.lstat(path)
    except OSError:
        existing = None
    if existing is not None and not stat.S_ISREG(existing.st_mode):
        raise InputFileError(f"{path} exists and is not a file; choose another path")
    if existing is not None and not is_cogmap_replay(path):
        raise InputFileError(f"{path} exists and is not a cogmap replay; choose another path")
    with replay.lock:
        log = replay.session.log.truncated(replay.cursor)
        params = replay.session.params
        judging = replay.session.evaluation
        finish = replay.at_end
    if log.frames == 0:
        raise InputFileError("nothing replayed yet: play some frames before saving a replay")
    try:  # before the (long) rendering: a folder we cannot write costs nothing
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(path.parent, exc, "create") from None
    check_writable(path.parent)
    bag = replay.bag_path.name if replay.bag_path is not None else ""
    page = html_replay(log, params, modes, finish, keyframes, seconds, bag, static_dir, judging)
    try:
        write_text_atomic(path, page)
    except OSError as exc:
        raise output_error(path, exc) from None
    if sent is not None:
        sent(page.encode())
    return path
