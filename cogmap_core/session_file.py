"""Session files: the whole SLAM state saved at the end of a run, resumed on another day.

A session holds everything that decides what happens next: the front end (view templates, the
pose cell network and its experiences, the last view), the three maps (graph arrays, aliases,
adjacency in its order, the loop-closure clusterer, scene integration's open and pending revisit
runs and its spatial index, the relocalisation gate's streak, the robot's state, counters, size
history, optimisation records), the map parameters, the front-end settings, the event log (so the
maps can be rebuilt for other parameters and evaluated against ground truth) and the data time.
Resuming it and processing more frames gives exactly what one run over all the data gives.

Format (``cogmap-session``, version 1): a NumPy ``.npz`` archive (zip, each member with its CRC;
no pickle, read with ``allow_pickle=False``). Member ``header`` is a 0-d unicode array holding
JSON (as Python writes it; ``NaN`` and ``Infinity`` may occur)::

    {"format": "cogmap-session", "version": 1, "cogmap": "0.1.0",
     "frontend": {...FrontEndConfig...}, "image_scale": 1, "params": {...MapParams...},
     "modes": ["standard", ...], "finished": false,
     "epoch": 1322449200.0, "data_time": 825.3, "frames": 14446, "events": 26209,
     "bags": [{"bag": "...", "offset": 0.0, "frames": 14446, "first": 0.01, "last": 825.3}],
     "state": {...scalars of every component...}, "arrays": {"name": [shape, dtype], ...}}

``epoch`` is the absolute time (s) data time counts from; each bag's frames were placed at
``offset`` + their time in the bag. Every other member is one array named by component, e.g.
``frontend.templates`` (uint8 ``(T, Y, X)``), ``frontend.pose_cells``, ``log.kind``,
``map.compact.graph.pose`` or ``map.compact.adjacency.neighbour``; ``header["arrays"]`` lists
them all with shape and dtype, and a file whose members do not match it is refused. Files are
written to a temporary name beside the target and renamed when complete. ``log.score`` (each
link's place-recognition score, NaN where none) may be absent: files written before it existed
load with no scores; ``map.<mode>.graph.edge_held`` (the links merges rest on) likewise, with
none held, and ``map.<mode>.graph.edge_cov`` (merged runs' evidence), with none kept.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core import __version__
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import ParameterError, StateError
from cogmap_core.event_log import EventLog
from cogmap_core.fileio import atomic_writer, load_archive
from cogmap_core.frontend import FrontEnd, FrontEndConfig
from cogmap_core.frontend.config import COGMAP_ARITHMETIC
from cogmap_core.session_arrays import Arrays, Json, SessionError, load_lists, save_lists
from cogmap_core.session_map import load_map, save_map
from cogmap_core.slam import SlamSession

FORMAT_NAME = "cogmap-session"
FORMAT_VERSION = 1

RESUME_GAP_S = 1.0
"""A bag whose clock does not continue the session's starts this long (s) after its end."""

#: The pose cells' scalars in ``state["frontend"]`` (:meth:`PoseCellExperiences.state_dict`).
_POSE_CELL_SCALARS = (
    "current_vt", "prev_vt", "current_exp", "vt_delta_th", "frame", "odo_update", "vt_update",
)  # fmt: skip
#: The event log's members (``log.NAME``, :meth:`EventLog.state_dict`), in the file's order;
#: ``score`` is absent from files written before it existed.
_LOG_ARRAYS = (
    "kind", "time", "ref", "view", "value0", "value1", "score",
    "frame_end", "frame_time", "has_truth", "truth",
)  # fmt: skip


@dataclass
class SessionMeta:
    """What a session knows about the data it has seen.

    Attributes:
        epoch: absolute time (s) that data time counts from (the first bag's start).
        image_scale: the JPEG decode reduction the front end saw frames at.
        bags: per bag processed, ``{"bag", "offset", "frames", "first", "last"}``: its frames
            were placed at ``offset`` plus their time in the bag.

    """

    epoch: float = 0.0
    image_scale: int = 1
    bags: list[dict[str, Any]] = field(default_factory=list)

    def resume_offset(self, bag_start: float, data_time: float) -> float:
        """Data-time offset of a new bag starting at absolute time ``bag_start`` (s).

        The bags' own clocks when the new one starts after the session's last frame (the robot
        was off for the gap between them); otherwise (a bag whose clock starts earlier, e.g. a
        generated one) it starts :data:`RESUME_GAP_S` after the session's last frame.
        """
        offset = bag_start - self.epoch
        if offset <= data_time:
            offset = data_time + RESUME_GAP_S
        return offset


# ============================================================================ writing
def save_session(path: Path | str, session: SlamSession, meta: SessionMeta) -> Path:
    """Write ``session`` to ``path`` atomically (a temporary file, then a rename)."""
    path = Path(path)
    state, arrays = _collect(session)
    log = session.log
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "cogmap": __version__,
        "frontend": session.frontend.config.to_dict(),
        "image_scale": meta.image_scale,
        "params": session.params.to_dict(),
        "modes": [m.value for m in session.modes],
        "finished": session.finished,
        "epoch": meta.epoch,
        "data_time": log.end_time,
        "frames": log.frames,
        "events": log.event_count,
        "bags": meta.bags,
        "state": state,
        "arrays": {name: [list(a.shape), a.dtype.str] for name, a in sorted(arrays.items())},
    }
    arrays["header"] = np.array(json.dumps(header, sort_keys=True))
    if not path.parent.is_dir():
        raise SessionError(f"{path}: folder {path.parent} does not exist; create it first")
    with atomic_writer(path, binary=True) as handle:
        np.savez_compressed(handle, **arrays)
    return path


def _collect(session: SlamSession) -> tuple[Json, Arrays]:
    """What a session file holds of ``session``: the state's scalars and its arrays."""
    state: Json = {}
    arrays: Arrays = {}
    _save_frontend(session.frontend, state, arrays)
    _save_log(session.log, arrays)
    state["maps"] = {}
    for mode, cmap in session.maps.maps.items():
        state["maps"][mode.value] = save_map(cmap, f"map.{mode.value}.", arrays)
    return state, arrays


def _save_frontend(frontend: FrontEnd, state: Json, arrays: Arrays) -> None:
    fe = frontend.state_dict()
    lv, pc = fe["local_view"], fe["pose_cells"]
    state["frontend"] = {
        "frames": fe["frames"],
        "last_time": fe["last_time"],
        "last_view": fe["last_view"],
        "indexed": lv["indexed"],
        "last_match": lv["last_match"],
        "best": pc["network"]["best"],
        **{name: pc[name] for name in _POSE_CELL_SCALARS},
    }
    arrays["frontend.templates"] = lv["templates"]
    arrays["frontend.key_signs"] = lv["key_signs"]
    arrays["frontend.pose_cells"] = pc["network"]["cells"]
    for name in ("view_cell_pose", "view_cell_decay", "view_cell_decay_frame"):
        arrays["frontend." + name] = pc[name]
    save_lists(arrays, "frontend.view_cell_experiences", pc["view_cell_experiences"])
    arrays["frontend.experiences"] = pc["experiences"]
    arrays["frontend.experience_view"] = pc["experience_view"]


def _save_log(log: EventLog, arrays: Arrays) -> None:
    state = log.state_dict()
    for name in _LOG_ARRAYS:
        arrays["log." + name] = state[name]


# ============================================================================ reading
def load_session(
    path: Path | str,
    frontend: FrontEndConfig | None = None,
    image_scale: int | None = None,
) -> tuple[SlamSession, SessionMeta]:
    """Read a session written by :func:`save_session`.

    With ``frontend`` (and ``image_scale``), a session made with other front-end settings (or
    decoded at another scale) is refused from its header alone, before any array is read and
    before its front end is built: a header's settings may ask for a pose cell network of many
    gigabytes.

    Raises:
        SessionError: missing, truncated or corrupt file, another format or version, contents
            that do not fit together, other front-end settings than ``frontend`` (one line
            naming the problem).

    """
    path = Path(path)

    def check_header(header: dict[str, Any]) -> None:
        if frontend is None and image_scale is None:
            return
        try:
            saved = _frontend_of(header)
            scale = int(header["image_scale"])
        except (KeyError, TypeError, ValueError, OverflowError, ParameterError) as exc:
            raise SessionError(
                f"{path}: the session's front-end settings cannot be read ({type(exc).__name__}: "
                f"{' '.join(str(exc).split())[:200]}); the file is corrupt"
            ) from None
        _refuse_other_settings(path, saved, scale, frontend, image_scale)

    header, arrays = load_archive(
        path,
        "session",
        FORMAT_NAME,
        FORMAT_VERSION,
        SessionError,
        advice="it is truncated or corrupt, use an intact copy",
        version_advice="resume it with the cogmap that wrote it or start a new session",
        check_header=check_header,
    )
    listed = header.get("arrays")
    if not isinstance(listed, dict) or set(listed) != set(arrays):
        raise SessionError(f"{path}: the session's arrays do not match its header; it is corrupt")
    for name, (shape, dtype) in listed.items():
        a = arrays[name]
        if list(a.shape) != shape or a.dtype.str != dtype:
            raise SessionError(
                f"{path}: array {name} is {a.dtype.str} {list(a.shape)}, the header says "
                f"{dtype} {shape}; the file is corrupt"
            )
    try:
        return _restore(header, arrays)
    except SessionError as exc:
        raise SessionError(f"{path}: {exc}") from None
    except (KeyError, IndexError, ValueError, TypeError, ParameterError) as exc:
        raise SessionError(
            f"{path}: the session's contents do not fit together ({type(exc).__name__}: {exc}); "
            "the file is corrupt"
        ) from None


def _frontend_of(header: Json) -> FrontEndConfig:
    """The session's front-end settings; a file from before issue 26 used cogmap's arithmetic."""
    return FrontEndConfig.from_dict({**COGMAP_ARITHMETIC, **header["frontend"]})


def _restore(header: Json, arrays: Arrays) -> tuple[SlamSession, SessionMeta]:
    config = _frontend_of(header)
    params = MapParams.from_dict(header["params"])
    modes = tuple(MapMode(m) for m in header["modes"])
    session = SlamSession(params, config, modes)
    state = header["state"]
    try:
        session.frontend = _load_frontend(config, state["frontend"], arrays)
    except StateError as exc:
        raise SessionError(str(exc)) from None
    session.log = _load_log(arrays)
    if session.log.frames != header["frames"] or session.log.event_count != header["events"]:
        raise SessionError("the event log does not match the header")
    for mode in modes:
        session.maps.maps[mode] = load_map(state["maps"][mode.value], f"map.{mode.value}.", arrays)
    session.finished = bool(header["finished"])
    meta = SessionMeta(
        epoch=float(header["epoch"]),
        image_scale=int(header["image_scale"]),
        bags=list(header["bags"]),
    )
    return session, meta


def _load_frontend(config: FrontEndConfig, s: Json, arrays: Arrays) -> FrontEnd:
    frontend = FrontEnd(config)
    pose_cells: Json = {name: s[name] for name in _POSE_CELL_SCALARS}
    pose_cells["network"] = {"cells": arrays["frontend.pose_cells"], "best": s["best"]}
    for name in ("view_cell_pose", "view_cell_decay", "view_cell_decay_frame"):
        pose_cells[name] = arrays["frontend." + name]
    pose_cells["view_cell_experiences"] = load_lists(arrays, "frontend.view_cell_experiences")
    pose_cells["experiences"] = arrays["frontend.experiences"]
    pose_cells["experience_view"] = arrays["frontend.experience_view"]
    frontend.load_state(
        {
            "frames": s["frames"],
            "last_time": s["last_time"],
            "last_view": s["last_view"],
            "local_view": {
                "templates": arrays["frontend.templates"],
                "key_signs": arrays["frontend.key_signs"],
                "indexed": s["indexed"],
                "last_match": s["last_match"],
            },
            "pose_cells": pose_cells,
        }
    )
    return frontend


def _load_log(arrays: Arrays) -> EventLog:
    # (log.score, links' place-recognition scores, is absent from older files)
    return EventLog.from_state(  # (ValueError when the frame ends do not match the events)
        {name: arrays["log." + name] for name in _LOG_ARRAYS if "log." + name in arrays}
    )


# ============================================================================ checks
def frontend_mismatch(saved: FrontEndConfig, wanted: FrontEndConfig) -> str | None:
    """The first setting in which two front-end configurations differ, as ``name=a vs b``."""
    a, b = saved.to_dict(), wanted.to_dict()
    for name in a:
        if a[name] != b[name]:
            return f"{name}={a[name]!r} (session) vs {b[name]!r} (this run)"
    return None


def check_resumable(
    path: Path | str, session: SlamSession, meta: SessionMeta, frontend: FrontEndConfig, scale: int
) -> None:
    """Refuse (one line) a session whose front end cannot continue on these settings."""
    _refuse_other_settings(path, session.frontend.config, meta.image_scale, frontend, scale)


def _refuse_other_settings(
    path: Path | str,
    saved: FrontEndConfig,
    saved_scale: int,
    frontend: FrontEndConfig | None,
    scale: int | None,
) -> None:
    if frontend is not None:
        mismatch = frontend_mismatch(saved, frontend)
        if mismatch is not None:
            raise SessionError(
                f"{path}: the session was made with other front-end settings: {mismatch}; resume "
                "with the same settings (the bag's profile and --frontend) or start a new session"
            )
    if scale is not None and saved_scale != scale:
        raise SessionError(
            f"{path}: the session's frames were decoded at 1/{saved_scale} scale, this run "
            f"decodes at 1/{scale}; resume with the same scale or start a new session"
        )


def resume_session(
    path: Path | str,
    frontend: FrontEndConfig,
    image_scale: int,
    param_changes: Mapping[str, float] | None = None,
) -> tuple[SlamSession, SessionMeta]:
    """Load a session to continue with these front-end settings and map parameter changes.

    The maps are rebuilt from the session's events when the changes alter its parameters.

    Raises:
        SessionError: unreadable file, other front-end settings or decode scale, or a session
            saved after its final optimisation.

    """
    session, meta = load_session(path, frontend, image_scale)  # settings checked before building
    check_resumable(path, session, meta, frontend, image_scale)
    if session.finished:
        raise SessionError(
            f"{path}: the session was saved after its final optimisation and cannot be continued "
            "exactly; save sessions with cogmap run --save-session"
        )
    params = session.params.with_changes(**dict(param_changes or {}))
    if params != session.params:
        session.adopt(params, session.rebuild(params, finish=False))
    return session, meta


def same_state(a: SlamSession, b: SlamSession) -> bool:
    """Whether two sessions hold exactly the same state (what a session file would hold).

    Optimisations' wall times are measurements, not state, and are not compared.
    """
    state_a, arrays_a = _collect(a)
    state_b, arrays_b = _collect(b)
    if json.dumps(state_a, sort_keys=True) != json.dumps(state_b, sort_keys=True):
        return False
    if set(arrays_a) != set(arrays_b):
        return False
    return all(
        _array_equal(arrays_a[k], arrays_b[k])
        for k in arrays_a
        if not k.endswith(".optimizations.wall_s")
    )


def _array_equal(a: NDArray[Any], b: NDArray[Any]) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def describe(meta: SessionMeta, session: SlamSession) -> str:
    """One line: data time, frames, bags and map sizes of a session."""
    log = session.log
    sizes = ", ".join(f"{m.value} {c.num_vertices} V" for m, c in session.maps.maps.items())
    return (
        f"{log.frames} frames, {log.end_time:.1f} s of data from {len(meta.bags)} bag(s), "
        f"{session.frontend.template_count} view templates; {sizes}"
    )


__all__: list[str] = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "RESUME_GAP_S",
    "SessionError",
    "SessionMeta",
    "check_resumable",
    "describe",
    "frontend_mismatch",
    "load_session",
    "resume_session",
    "same_state",
    "save_session",
]
