"""The replay's maps rebuilt: for new parameters, and for a new position (a restart or a seek).

A part of :class:`~app.server.replay.Replay` (its worker thread runs these; the class is made of
:class:`ReplayRebuilds` and the playback in :mod:`app.server.replay`). After a parameter change
each map is *kept* (the change does not affect it, :data:`PARAMS_USED`, or leaves its cluster
schedule as it is), taken from the :class:`~app.server.rebuild.MapCache` (built before for these
parameters) or *built* by the :class:`~app.server.rebuild.Builder`; the displayed maps first, the
latest request winning (a newer one abandons the rebuild). A restart or a seek backwards rebuilds
the maps up to the new position from the session's cached events the same way.

A map to be built whose last build took longer than :data:`~app.server.preview.PREVIEW_AFTER_S`
(or that was never built) is first shown as a *preview* (:mod:`app.server.preview`): kept in
``previews``, drawn instead of the session's map until its exact map is published, never adopted.
"""

from __future__ import annotations

import bisect
import copy
import math
import threading
import time
from typing import TYPE_CHECKING

from app.server import preview as preview_module
from app.server.preview import Preview, make_preview, preview_difference
from app.server.rebuild import Abandoned, Builder, BuildTask, MapCache
from app.server.replay_state import PlaybackState, RebuildRecord
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.parameter_table import PARAMETERS_USED
from cogmap_core.schedule import same_schedule
from cogmap_core.slam import ALL_MODES, SlamSession

if TYPE_CHECKING:
    from cogmap_core.sources.detect import Source

#: The map parameters each map depends on (the ``maps`` of each row of the parameter table,
#: :mod:`cogmap_core.parameter_table`). A change of other parameters leaves a map exactly as
#: it is, so its rebuild is skipped (the neighborhood field and short-edge removal belong to the
#: compact map only, scene integration to the two non-standard maps). The tests rebuild every map
#: for a change of every parameter and check this table.
PARAMS_USED: dict[MapMode, frozenset[str]] = PARAMETERS_USED


def needs_rebuild(mode: MapMode, old: MapParams, new: MapParams) -> bool:
    """Whether map ``mode`` built with ``old`` can differ from one built with ``new``."""
    return any(getattr(old, name) != getattr(new, name) for name in PARAMS_USED[mode])


def _label_params(maps: dict[MapMode, CognitiveMap], params: MapParams) -> None:
    """Give maps taken from the cache the parameters they are adopted with.

    A cached map was built with parameters that agree with ``params`` in every one it uses
    (:data:`PARAMS_USED`) but may differ in the others; it must carry ``params`` so that later
    changes compare against what is in force.
    """
    for cmap in maps.values():
        if cmap.params != params:
            cmap.set_params(params)


class ReplayRebuilds:
    """The rebuilds of :class:`~app.server.replay.Replay` (module doc); its worker calls them.

    The attributes below are the replay's (set up by its constructor); so are the methods this
    part calls: ``_bag_time``, ``_notify_maps``, ``_notify_status``, ``_open``,
    ``_start_pass``, ``_show_current`` and ``_update_state_locked``.
    """

    session: SlamSession
    lock: threading.RLock
    _cond: threading.Condition
    _target_params: MapParams
    _params_request: float | None
    _seek_request: float | None
    _restart_request: bool
    _fast_forward_to: float | None
    _generation: int
    _priority: tuple[MapMode, ...]
    _anchor: tuple[float, float] | None
    _base_maps: dict[MapMode, CognitiveMap]
    _base_params: MapParams
    _log_id: int
    base_frames: int
    time_offset: float
    cursor: int
    at_end: bool
    state: PlaybackState
    message: str
    reader: Source | None
    frame_time: float
    processing_s: float
    rebuilding: tuple[MapParams, tuple[MapMode, ...]] | None
    rebuilds: list[RebuildRecord]
    previews: dict[MapMode, Preview]
    builder: Builder
    cache: MapCache

    # ------------------------------------------------------------------ restart, seek
    def shown_maps(self) -> dict[MapMode, CognitiveMap]:
        """The maps to draw: the session's, a map being rebuilt by its preview (call locked)."""
        maps = dict(self.session.maps.maps)
        maps.update({mode: p.cmap for mode, p in self.previews.items() if mode in maps})
        return maps

    def _drop_previews(self) -> bool:
        """Forget the previews shown (True if there were any)."""
        with self.lock:
            dropped = bool(self.previews)
            self.previews.clear()
        return dropped

    def _do_restart(self) -> None:
        self._drop_previews()
        with self._cond:
            self._restart_request = False
            self._fast_forward_to = None
        if self.reader is None or self.state is PlaybackState.ERROR:
            with self._cond:
                self.state = PlaybackState.LOADING
            if self.reader is None:
                self._open()
                return
        self._seek_to_frame(0)

    def _do_seek(self) -> None:
        with self._cond:
            target = self._seek_request
            self._seek_request = None
            self._fast_forward_to = None
        assert target is not None
        if self.reader is None:
            return
        if self.state is PlaybackState.ERROR:  # seeking re-reads the bag, like a restart
            with self._cond:
                self.state = PlaybackState.LOADING
        log = self.session.log
        cached_end = self._bag_time(log.frame_time[-1]) if log.frames else -math.inf
        try:
            if target <= cached_end or self.session.finished:
                k = bisect.bisect_right(log.frame_time, target + self.time_offset)
                self._seek_to_frame(k)
            else:
                # Beyond what the front end has seen: replay the cache to its end, then run the
                # front end as fast as possible up to the target.
                if self.cursor < log.frames or self.at_end:
                    self._seek_to_frame(log.frames)
                with self._cond:
                    self._fast_forward_to = target
        except Abandoned:
            with self._cond:
                if self._seek_request is None and not self._restart_request:
                    self._seek_request = target  # interrupted by parameters: seek again
            raise

    def _seek_to_frame(self, k: int) -> None:
        """Rebuild the maps up to frame ``k`` from the cache and continue reading from there."""
        with self._cond:
            generation = self._generation
            params = self._target_params
            self._params_request = None
        log = self.session.log
        base = self.base_frames
        k = max(base, min(k, log.frames))
        maps: dict[MapMode, CognitiveMap] = {}
        tasks = []
        if k == base and self._base_maps and params == self._base_params:
            # back to the resumed state: the session's own maps (nothing to rebuild)
            maps = {mode: copy.deepcopy(cmap) for mode, cmap in self._base_maps.items()}
        else:
            for mode in self._order():
                cached = self.cache.take(self.cache.key(mode, params, k, False, self._log_id))
                if cached is not None:
                    maps[mode] = cached
                else:
                    tasks.append(BuildTask(mode, params, k, False))
        try:
            for built in self.builder.build(log, tasks, lambda: self._generation != generation):
                maps[built.task.mode] = built.cmap
        except Abandoned:
            for mode, cmap in maps.items():  # what was done is kept for the next time
                self.cache.put(self.cache.key(mode, params, k, False, self._log_id), cmap)
            raise
        with self.lock:
            self._keep_replaced(maps)
            _label_params(maps, params)
            self.session.adopt(params, maps)
            self.previews.clear()
            self.session.finished = False
            if k == base:
                self.processing_s = 0.0
            self.cursor = k
            self.at_end = False
            self.frame_time = self._bag_time(log.frame_time[k - 1]) if k > base else math.nan
        if self.state is not PlaybackState.ERROR:
            if k > base:
                # from the frame the maps now end with: it is shown (the camera at once after a
                # seek, not an old frame until a step), then the frames after it are read
                t = log.frame_time[k - 1]
                before = log.frame_time[k - 2] if k - 1 > base else t - 1.0
                start = max(0.0, self._bag_time(t) - min(1e-3, (t - before) / 2))
                self._start_pass(start)
                self._show_current(k)
            else:
                self._start_pass(0.0)
        with self._cond:
            if self.state is PlaybackState.LOADING:
                self.state = PlaybackState.PAUSED
            self.message = ""
        self._update_state_locked()
        self._notify_maps(ALL_MODES, True)
        self._notify_status()

    # ------------------------------------------------------------------ parameter rebuilds
    def _order(self) -> tuple[MapMode, ...]:
        first = tuple(m for m in self._priority if m in self.session.modes)
        return first + tuple(m for m in self.session.modes if m not in first)

    def _keep_replaced(self, maps: dict[MapMode, CognitiveMap]) -> None:
        """Put the current maps that ``maps`` replace into the cache (call with the lock)."""
        for mode, cmap in maps.items():
            old = self.session.maps.maps.get(mode)
            if old is not None and old is not cmap:
                key = self.cache.key(mode, old.params, self.cursor, self.at_end, self._log_id)
                self.cache.put(key, old)

    def _do_rebuild(self) -> None:
        with self._cond:
            params = self._target_params
            requested = self._params_request
            self._params_request = None
            generation = self._generation
        assert requested is not None
        frames = self.cursor
        finish = self.at_end
        record = RebuildRecord(params, frames, requested)
        self.rebuilds.append(record)
        if self.state is PlaybackState.ERROR and self.reader is None:
            # Nothing to rebuild from (the bag never opened): keep the parameters for later.
            with self.lock:
                self.session.params = params
            return
        maps = self.session.maps
        self.rebuilding = (  # the maps the change can affect (a few may turn out unchanged)
            params,
            tuple(m for m in self._order() if needs_rebuild(m, maps[m].params, params)),
        )
        self._notify_status()  # (the page shows that the maps are being rebuilt)
        try:
            self._rebuild(record, params, frames, finish, generation)
        finally:
            self.rebuilding = None
        with self._cond:
            self._anchor = None
        self._notify_maps((), True)  # the pages' "shown after" line now covers this change
        self._notify_status()

    def _rebuild(
        self, record: RebuildRecord, params: MapParams, frames: int, finish: bool, generation: int
    ) -> None:
        log = self.session.log
        dropped = self._drop_previews()  # (an abandoned rebuild's: each map is shown anew)
        tasks = []
        unchanged: dict[MapParams, bool] = {}  # per parameters in use (the maps mostly share)
        for mode in self._order():
            started = time.perf_counter()
            current = self.session.maps[mode]
            keep = not needs_rebuild(mode, current.params, params)
            if not keep:
                if current.params not in unchanged:
                    unchanged[current.params] = same_schedule(
                        log, frames, finish, current.params, params
                    )
                keep = unchanged[current.params]
            if keep:
                cmap: CognitiveMap | None = current  # the change leaves this map as it is
                with self.lock:
                    current.set_params(params)
                record.how[mode] = "kept"
            else:
                cmap = self.cache.take(self.cache.key(mode, params, frames, finish, self._log_id))
                if cmap is not None:  # (a miss is built below; an abandoned build says nothing)
                    record.how[mode] = "cached"
            if cmap is None:
                tasks.append(BuildTask(mode, params, frames, finish))
                continue
            self._publish_rebuilt(record, mode, params, cmap, time.perf_counter() - started)
        self._publish_previews(record, params, tuple(task.mode for task in tasks), dropped)
        for built in self.builder.build(log, tasks, lambda: self._generation != generation):
            record.how[built.task.mode] = "built"
            record.resumed[built.task.mode] = built.resumed_at
            self._publish_rebuilt(record, built.task.mode, params, built.cmap, built.compute_s)
        record.completed = True

    def _last_build_s(self, mode: MapMode) -> float | None:
        """How long the last build of map ``mode`` took (s; None: never built after a change)."""
        for record in reversed(self.rebuilds):
            if record.how.get(mode) == "built" and mode in record.compute_s:
                return record.compute_s[mode]
        return None

    def _publish_previews(
        self,
        record: RebuildRecord,
        params: MapParams,
        modes: tuple[MapMode, ...],
        redraw: bool = False,
    ) -> None:
        """Show a preview of each of ``modes`` (to be built) whose build is slow, if it has one.

        ``redraw``: the maps are drawn again even without a preview (previews were dropped).
        """
        shown: dict[MapMode, Preview] = {}
        maps = self.session.maps.maps  # (only this thread changes them)
        for mode in modes:
            last = self._last_build_s(mode)
            if last is not None and last <= preview_module.PREVIEW_AFTER_S:
                continue
            preview = make_preview(mode, maps[mode], maps.get(MapMode.STANDARD), params)
            if preview is not None:
                shown[mode] = preview
        if shown:
            with self.lock:
                self.previews.update(shown)
        if shown or redraw:
            self._notify_maps((), True)  # (drawn: no accuracy figures for a preview)
            now = time.perf_counter()
            for mode in shown:
                record.previewed[mode] = now

    def _publish_rebuilt(
        self,
        record: RebuildRecord,
        mode: MapMode,
        params: MapParams,
        cmap: CognitiveMap,
        compute_s: float,
    ) -> None:
        record.compute_s[mode] = compute_s
        previewed = self.previews.get(mode)
        if previewed is not None:
            record.preview_difference[mode] = preview_difference(previewed.cmap, cmap)
        with self.lock:
            self._keep_replaced({mode: cmap})
            _label_params({mode: cmap}, params)
            self.session.adopt(params, {mode: cmap})
            self.previews.pop(mode, None)
        pending = self.rebuilding
        if pending is not None:
            self.rebuilding = (pending[0], tuple(m for m in pending[1] if m is not mode))
        self._notify_maps((mode,), True)
        record.published[mode] = time.perf_counter()
