"""The replay worker: one thread that owns the SLAM session and replays the input through it.

The input is a bag (camera frames through the front end) or a log of odometry and place
recognition (steps with their events, :mod:`cogmap_core.sources`); it is opened with
:func:`~cogmap_core.sources.detect.open_source` and replayed the same way.

The worker reads frames at the playback speed and feeds them to a
:class:`~cogmap_core.slam.SlamSession`. Every other thread (GUI callbacks of any number of clients)
only *requests* things -- new map parameters, play/pause, speed, step, restart, seek -- by setting
a field under a condition variable; the latest request wins, so a storm of slider events never
queues work: a rebuild in progress is abandoned as soon as a newer parameter set arrives.

The front end runs once per frame of the bag; its events are cached in the session's log. Frames
the front end has already seen are replayed from that cache (restart, seek backwards, parameter
changes), so the maps depend only on the data and the parameters, never on playback speed or on
when a slider moved. The bag is re-read only for the camera images of cached frames.

Listeners are called from the worker thread only (:class:`ReplayListener`); everything that reads
the maps from another thread takes :attr:`Replay.lock`.

This module has the requests, the worker's loop, opening the input and playback; the rebuilds
(new parameters, restart, seek) are in :mod:`app.server.replay_rebuilds`, the state the page
reads (:class:`PlaybackState`, :class:`RebuildRecord`) in :mod:`app.server.replay_state`.
"""

from __future__ import annotations

import array
import copy
import math
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Protocol

from app.inputs import ReplayInput
from app.server.preview import Preview
from app.server.rebuild import Abandoned, Builder, MapCache, ThreadBuilder
from app.server.replay_rebuilds import PARAMS_USED, ReplayRebuilds, needs_rebuild
from app.server.replay_state import PlaybackState, RebuildRecord
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets import BagReader
from cogmap_core.errors import CogmapError
from cogmap_core.frames import EventStep, Frame
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.session_file import SessionMeta
from cogmap_core.slam import ALL_MODES, SlamSession
from cogmap_core.sources.detect import (
    KINDS,
    Source,
    check_sessions_allowed,
    open_source,
    resolve_format,
)

__all__ = [
    "PARAMS_USED",
    "PlaybackState",
    "RebuildRecord",
    "Replay",
    "ReplayListener",
    "needs_rebuild",
]


#: A replay that falls further behind its schedule than this (s) re-anchors instead of racing.
MAX_LAG_S = 1.0
_TIME_TOLERANCE = 1e-6


class ReplayListener(Protocol):
    """Receives the worker's updates, always on the worker thread."""

    def on_status(self, replay: Replay) -> None:
        """The playback state, message or position changed."""

    def on_frame(self, replay: Replay, frame: Frame | EventStep, view_template: int | None) -> None:
        """A frame was replayed (its camera image and matched view template; a log's step)."""

    def on_maps(self, replay: Replay, modes: tuple[MapMode, ...], forced: bool) -> None:
        """The maps ``modes`` changed; ``forced``: show it now (not rate-limited)."""


class Replay(ReplayRebuilds):
    """Replays one bag or log through a :class:`SlamSession` on a worker thread.

    Args:
        source: what is replayed and how it is read (:class:`~app.inputs.ReplayInput`: the bag
            or log, or a function that produces it given a progress callback -- the built-in
            dataset, generated on first use --, its kind, front end, topics, log options, ...).
        listener: receives updates (on the worker thread).
        params: initial map parameters.
        speed: playback speed (data seconds per wall second; ``math.inf``: as fast as possible).
        autoplay: start playing as soon as the bag is open.
        priority: maps rebuilt first after a parameter change (the displayed ones).
        builder: where maps are rebuilt (:mod:`app.server.rebuild`; default: this thread). The
            replay owns it and closes it when stopped.
        resume: a saved session and its metadata (:func:`~cogmap_core.session_file.load_session`)
            to continue: its maps are shown at once and grow with the bag's frames, which follow
            the session's data as if the bags were one. Restarting or seeking goes back no
            further than the session's end. Bags only: a log with a session is refused.
        lock: guards the worker-owned state (below).
        opened: the input already open (below).

    Times: :attr:`frame_time`, :attr:`duration` and :meth:`seek` are positions in the bag;
    the session's data time of bag time ``t`` is ``t +`` :attr:`time_offset` (0 unless
    resuming), and :attr:`cursor` counts the session's frames (those of the resumed session
    first, :attr:`base_frames` of them).

    The worker's rebuilds (parameters, restart, seek) are in :mod:`app.server.replay_rebuilds`.

    """

    def __init__(
        self,
        source: ReplayInput,
        listener: ReplayListener,
        params: MapParams | None = None,
        speed: float = 1.0,
        autoplay: bool = True,
        priority: tuple[MapMode, ...] = (MapMode.COMPACT,),
        builder: Builder | None = None,
        resume: tuple[SlamSession, SessionMeta] | None = None,
        lock: threading.RLock | None = None,
        opened: Source | None = None,
    ) -> None:
        """Set up the replay (nothing is read until :meth:`start`).

        ``lock`` guards the worker-owned state; an app that swaps replays passes one lock to
        all of them, so a reader that took ``app.replay.lock`` holds the lock of the replay it
        then finds in ``app.replay``. ``opened`` is the input ``source`` names already open (a
        caller that checked it hands it over instead of having it opened twice); the replay
        closes it.
        """
        self.source = source
        self.has_camera = True  # known once the input is open
        self.listener = listener
        frontend = source.options.frontend
        self.frontend_config: FrontEndConfig | None = (
            frontend if isinstance(frontend, FrontEndConfig) else None
        )
        self.lock = lock if lock is not None else threading.RLock()
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        # requests (guarded by _cond)
        self._target_params = params or MapParams()
        self._params_request: float | None = None  # perf_counter of the pending params request
        self._seek_request: float | None = None
        self._restart_request = False
        self._step_request = 0
        self._playing = autoplay
        self._speed = speed
        self._priority: tuple[MapMode, ...] = priority
        self._stopping = False
        self._generation = 0  # bumped by every request that should interrupt a rebuild
        # worker-owned state (read by others under `lock`)
        self.session = SlamSession(self._target_params, self.frontend_config)
        self.resume_meta: SessionMeta | None = None
        self._base_maps: dict[MapMode, CognitiveMap] = {}
        if resume is not None:
            self.session, self.resume_meta = resume
            self.frontend_config = self.session.frontend.config
            self._target_params = self.session.params
            self._base_maps = {m: copy.deepcopy(c) for m, c in self.session.maps.maps.items()}
        self._base_params = self.session.params
        self.base_frames = self.session.log.frames  # frames of the resumed session
        self.time_offset = 0.0  # session data time of the bag's time 0
        self.cursor = self.base_frames  # frames applied to the maps
        self.at_end = False
        self.state = PlaybackState.LOADING
        self.message = "opening the bag"
        self.bag_path: Path | None = None
        self.reader: Source | None = None
        self._opened = opened  # handed over by the caller, used by _open
        self.duration = 0.0
        self.total_frames = 0
        # per frame of the bag, the view template it matched (-1: none) and the match error
        # (NaN: a new template, or none); 16 bytes a frame
        self.view_templates = array.array("q")
        self.view_errors = array.array("d")
        #: a parameter change being rebuilt: (its parameters, the maps still to show), or None
        self.rebuilding: tuple[MapParams, tuple[MapMode, ...]] | None = None
        self.rebuilds: list[RebuildRecord] = []
        #: maps drawn before their exact rebuild arrives (:mod:`app.server.preview`); never in
        #: the session (read under ``lock``)
        self.previews: dict[MapMode, Preview] = {}
        self.frame_time = math.nan  # data time of the last frame applied
        self.processing_s = 0.0  # wall time spent applying frames (front end + maps)
        self._frames: Iterator[Frame | EventStep] | None = None
        self._next: Frame | EventStep | None = None
        self._anchor: tuple[float, float] | None = None  # (wall, data time)
        self._fast_forward_to: float | None = None
        self._busy = 0  # 1 while the worker handles a request or a frame
        self.builder: Builder = builder or ThreadBuilder()
        self.cache = MapCache(uses=PARAMS_USED)
        self._log_id = 0  # bumped with every new session (the cache's maps belong to one)

    # ================================================================== requests (any thread)
    def start(self) -> None:
        """Start the worker thread."""
        self._thread = threading.Thread(target=self._run, name="cogmap-replay", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the worker (abandoning any rebuild) and close the bag."""
        with self._cond:
            self._stopping = True
            self._generation += 1
            self._cond.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        elif self._thread is None and self._opened is not None:  # never started: nobody else will
            self._opened.close()
            self._opened = None
        self.builder.close()

    @property
    def alive(self) -> bool:
        """Whether the worker thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def set_params(self, params: MapParams) -> None:
        """Rebuild the maps for ``params`` (the latest call wins)."""
        with self._cond:
            self._target_params = params
            self._params_request = time.perf_counter()
            self._generation += 1
            self._cond.notify_all()

    @property
    def params(self) -> MapParams:
        """The parameters the maps are (being) built with."""
        return self._target_params

    def play(self) -> None:
        """Play from the current position."""
        with self._cond:
            self._playing = True
            self._anchor = None
            self._cond.notify_all()

    def pause(self) -> None:
        """Pause after the current frame."""
        with self._cond:
            self._playing = False
            self._cond.notify_all()

    @property
    def playing(self) -> bool:
        """Whether playback is on (it may be waiting for a rebuild or at the end)."""
        return self._playing

    def set_speed(self, speed: float) -> None:
        """Playback speed: data seconds per wall second (``math.inf``: as fast as possible)."""
        if not (speed > 0):
            raise ValueError(f"speed {speed} must be > 0")
        with self._cond:
            self._speed = speed
            self._anchor = None
            self._cond.notify_all()

    @property
    def speed(self) -> float:
        """Playback speed."""
        return self._speed

    def step(self, frames: int = 1) -> None:
        """Pause and replay ``frames`` more frames."""
        with self._cond:
            self._playing = False
            self._step_request += frames
            self._cond.notify_all()

    def restart(self) -> None:
        """Back to the first frame (re-opening the bag after an error)."""
        with self._cond:
            self._restart_request = True
            self._seek_request = None
            self._generation += 1
            self._cond.notify_all()

    def seek(self, data_time: float) -> None:
        """Jump to data time ``data_time`` (s); the latest call wins."""
        if not math.isfinite(data_time):
            raise ValueError(f"seek time {data_time} is not finite")
        with self._cond:
            self._seek_request = max(0.0, float(data_time))
            self._generation += 1
            self._cond.notify_all()

    def set_priority(self, modes: tuple[MapMode, ...]) -> None:
        """Maps to rebuild first after a parameter change (the displayed ones)."""
        with self._cond:
            self._priority = tuple(modes)

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Wait until no request is pending and playback is paused or ended (tests)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._cond:
                idle = (
                    self._params_request is None
                    and self._seek_request is None
                    and not self._restart_request
                    and self._step_request == 0
                    and self._fast_forward_to is None
                    and (
                        not self._playing
                        or self.state in (PlaybackState.ENDED, PlaybackState.ERROR)
                    )
                    and self.state is not PlaybackState.LOADING
                    and self._busy == 0
                )
            if idle:
                return True
            time.sleep(0.01)
        return False

    # ================================================================== worker
    def _run(self) -> None:
        self._busy = 1
        try:
            self._open()
        finally:
            self._busy = 0
        while True:
            with self._cond:
                if self._stopping:
                    break
                restart = self._restart_request
                seek = self._seek_request
                params_pending = self._params_request is not None
                stepping = self._step_request > 0
                run = self._playing or stepping or self._fast_forward_to is not None
                can_run = self.state not in (PlaybackState.ERROR, PlaybackState.LOADING)
                if not (restart or seek is not None or params_pending) and not (
                    run and can_run and not self.at_end
                ):
                    if self.at_end or not can_run:
                        self._step_request = 0
                        self._fast_forward_to = None
                    self._update_state_locked()
                    self._cond.wait(0.25)
                    idle = True
                else:
                    idle = False
                    self._busy = 1
                    self._update_state_locked()  # e.g. paused -> playing
            if idle:
                if self.state is not PlaybackState.LOADING:
                    self.builder.prepare(self.session.log)  # the next rebuild starts at once
                continue
            try:
                if restart:
                    self._do_restart()
                elif seek is not None:
                    self._do_seek()
                elif params_pending:
                    self._do_rebuild()
                else:
                    self._do_advance(stepping)
            except Abandoned:
                pass
            except CogmapError as exc:
                self._fail(str(exc))
            except Exception as exc:  # a bug must not take the server down
                traceback.print_exc(file=sys.stderr)
                self._fail(f"internal error: {type(exc).__name__}: {exc}")
            finally:
                self._busy = 0
        self._close_pass()
        if self.reader is not None:
            self.reader.close()
        if self._opened is not None:  # stopped before it was used
            self._opened.close()
            self._opened = None

    def _update_state_locked(self) -> None:
        state = self.state
        if state in (PlaybackState.ERROR, PlaybackState.LOADING):
            return
        new = (
            PlaybackState.ENDED
            if self.at_end
            else (PlaybackState.PLAYING if self._playing else PlaybackState.PAUSED)
        )
        if new is not state:
            self.state = new
            self._notify_status()

    def _notify_status(self) -> None:
        try:
            self.listener.on_status(self)
        except Exception:  # a listener problem must not stop the replay
            traceback.print_exc(file=sys.stderr)

    def last_completed_rebuild(self) -> RebuildRecord | None:
        """The latest parameter change whose maps are all shown (None before any)."""
        return next((b for b in reversed(self.rebuilds) if b.completed), None)

    def _notify_maps(self, modes: tuple[MapMode, ...], forced: bool) -> None:
        try:
            self.listener.on_maps(self, modes, forced)
        except Exception:
            traceback.print_exc(file=sys.stderr)

    def _fail(self, message: str) -> None:
        self._close_pass()
        with self._cond:
            self.state = PlaybackState.ERROR
            self.message = message
            self._fast_forward_to = None
            self._step_request = 0
        print(f"cogmap serve: error: {message}", file=sys.stderr)
        self._notify_status()
        self._notify_maps(ALL_MODES, True)

    # ------------------------------------------------------------------ opening
    def _open(self) -> None:
        self.state = PlaybackState.LOADING
        self.message = "opening the bag"
        self._notify_status()
        try:
            path = self._resolve_bag()
            self.bag_path = path
            options = self.source.options
            fmt = resolve_format(path, options.format)
            if self.resume_meta is not None:
                check_sessions_allowed(fmt, path, "--resume", "serve it without --resume")
            reader, self._opened = self._opened, None
            if reader is None:
                reader = open_source(
                    path,
                    fmt,
                    topics=options.topics,
                    image_scale=options.image_scale,
                    log=options.log,
                    camera=options.camera_for(path),
                )
            self.has_camera = KINDS[fmt].has_camera
            if self.session.log.frames == 0:  # the front end is chosen for the input
                self._choose_frontend(path, fmt)
            if self.resume_meta is not None and self.base_frames:
                assert isinstance(reader, BagReader)
                end = float(self.session.log.frame_time[self.base_frames - 1])
                self.time_offset = self.resume_meta.resume_offset(reader.start_stamp, end)
        except CogmapError as exc:
            self._fail(str(exc))
            return
        except Exception as exc:
            traceback.print_exc(file=sys.stderr)
            self._fail(f"cannot open the bag: {type(exc).__name__}: {exc}")
            return
        with self.lock:
            if self.reader is not None:
                self.reader.close()
            self.reader = reader
            self.duration = reader.info.duration
            self.total_frames = self.base_frames + reader.info.frame_count
        self.message = ""
        self._start_pass(0.0)
        with self._cond:
            self.state = PlaybackState.PLAYING if self._playing else PlaybackState.PAUSED
        self._notify_status()
        self._notify_maps(ALL_MODES, True)

    @property
    def format(self) -> str | None:
        """The input's kind as given (None: detected from the content when it is opened)."""
        return self.source.options.format

    def _choose_frontend(self, path: Path, fmt: str) -> None:
        kind = KINDS[fmt]
        config = self.source.options.frontend_for(path) if kind.has_camera else None
        with self.lock:
            self.frontend_config = config
            self.session = SlamSession(self._target_params, config, evaluation=kind.evaluation)
            self._log_id += 1
            self.cache.clear()  # (the builder's workers notice a new log by themselves)

    def _resolve_bag(self) -> Path:
        source = self.source.bag
        if isinstance(source, Path):
            return source

        def progress(done: int, total: int) -> None:
            self.message = f"generating the built-in dataset: {done}/{total} frames"
            self._notify_status()

        self.message = "preparing the built-in dataset"
        self._notify_status()
        return source(progress)

    def _bag_time(self, data_time: float) -> float:
        """Position in the bag of a session data time."""
        return float(data_time) - self.time_offset

    @property
    def data_time(self) -> float:
        """Session data time of the last frame applied (nan before any)."""
        k = self.cursor
        return float(self.session.log.frame_time[k - 1]) if k else math.nan

    def _start_pass(self, start_time: float) -> None:
        """Read the bag from bag time ``start_time``."""
        self._close_pass()
        assert self.reader is not None
        self._frames = self.reader.frames(start_time)
        self._next = None
        self._anchor = None

    def _close_pass(self) -> None:
        frames = self._frames
        self._frames = None
        self._next = None
        if frames is not None and hasattr(frames, "close"):
            frames.close()  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ playback
    def _peek(self) -> Frame | EventStep | None:
        if self._next is None and self._frames is not None:
            self._next = next(self._frames, None)
        return self._next

    def _do_advance(self, stepping: bool) -> None:
        frame = self._peek()
        if frame is None:
            self._finish_pass()
            return
        with self._cond:
            fast = self._fast_forward_to is not None
            speed = math.inf if (fast or stepping) else self._speed
            if math.isfinite(speed):
                now = time.perf_counter()
                if self._anchor is None:
                    self._anchor = (now, frame.time)
                wall0, data0 = self._anchor
                delay = wall0 + (frame.time - data0) / speed - now
                if delay > 0:
                    self._cond.wait(delay)
                    return  # re-check requests; the frame stays peeked
                if delay < -MAX_LAG_S:
                    self._anchor = (now, frame.time)
        self._apply_frame(frame)
        self._next = None
        with self._cond:
            if stepping and self._step_request > 0:
                self._step_request -= 1
            if self._fast_forward_to is not None and frame.time >= self._fast_forward_to:
                self._fast_forward_to = None
                fast = False
                self._anchor = None
        forced = stepping or not (self._playing or fast)
        self._notify_maps(ALL_MODES, forced)
        self._notify_status()

    def _apply_frame(self, frame: Frame | EventStep) -> None:
        session = self.session
        log = session.log
        started = time.perf_counter()
        if self.time_offset:
            frame = replace(frame, time=frame.time + self.time_offset)
        with self.lock:
            k = self.cursor
            if k < log.frames:
                expected = log.frame_time[k]
                if abs(frame.time - expected) > _TIME_TOLERANCE:
                    raise CogmapError(
                        f"the bag changed while replaying: frame {k} is at {frame.time:.6f} s, "
                        f"the cache has it at {expected:.6f} s; restart the server"
                    )
                lo = log.frame_end[k - 1] if k else 0
                for event in log.events[lo : log.frame_end[k]]:
                    session.maps.apply(event)
                matched = self.view_templates[k - self.base_frames]
                view = None if matched < 0 else matched
            else:
                out = session.process(frame)
                self.view_templates.append(-1 if out.view_template is None else out.view_template)
                last = session.frontend.last_view if isinstance(frame, Frame) else None
                error = None if last is None or last.is_new else last.error
                self.view_errors.append(math.nan if error is None else error)
                view = out.view_template
            self.cursor = k + 1
            self.frame_time = self._bag_time(frame.time)
            self.processing_s += time.perf_counter() - started
        try:
            self.listener.on_frame(self, frame, view)
        except Exception:
            traceback.print_exc(file=sys.stderr)

    def _finish_pass(self) -> None:
        session = self.session
        started = time.perf_counter()
        with self.lock:
            if self.cursor == session.log.frames:
                session.finish()
            elif self.cursor:
                session.maps.finish(float(session.log.frame_time[self.cursor - 1]))
            self.at_end = True
            self.processing_s += time.perf_counter() - started
        self._close_pass()
        with self._cond:
            self._fast_forward_to = None
            self._step_request = 0
            self._playing = False  # ended: a seek stays there; play starts over (the page)
        self._update_state_locked()
        self._notify_maps(ALL_MODES, True)
        self._notify_status()

    def _show_current(self, k: int) -> None:
        """Read frame ``k - 1`` again and show it (:meth:`ReplayListener.on_frame`), not applied.

        Frames before it are dropped; a frame after it is left to be read in turn.
        """
        expected = self.session.log.frame_time[k - 1]
        while True:
            frame = self._peek()
            if frame is None or frame.time + self.time_offset > expected + _TIME_TOLERANCE:
                return
            self._next = None
            if frame.time + self.time_offset >= expected - _TIME_TOLERANCE:
                break
        if self.time_offset:
            frame = replace(frame, time=frame.time + self.time_offset)
        matched = self.view_templates[k - 1 - self.base_frames] if self.view_templates else -1
        try:
            self.listener.on_frame(self, frame, None if matched < 0 else matched)
        except Exception:
            traceback.print_exc(file=sys.stderr)
