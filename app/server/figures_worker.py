"""The accuracy figures of the three maps, computed on a thread of their own for the page.

They take some 30 ms per map (the layout fidelity most), so the page only *asks* for them
(:meth:`FiguresWorker.request`: once a second, at once for rebuilt maps) and this worker computes
them after the map is shown; the page then shows them (the counters, the truth's alignment and
the false loop closures in the scene) and the views follow.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any

from app.server.figures import (
    NO_LINKS,
    FigureInputs,
    LinkJudgement,
    MapFigures,
    compute_figures,
    false_link_inputs,
    figure_inputs,
    judge_links,
)
from app.server.timing import RateLimit
from app.server.worker import Worker
from cogmap_core.cognitive_map import MapMode
from cogmap_core.slam import ALL_MODES

if TYPE_CHECKING:
    from app.server.replay import Replay


class FiguresWorker(Worker[list[MapMode]]):
    """Computes the figures of the maps of ``current()``'s replay (module doc).

    Args:
        current: the page's replay now (the page swaps it for another input's).
        scene_lock: the page's scene lock, held with the replay's while the figures are stored.
        show: called with both locks held once figures were stored (publish the scene, write
            the counters).
        refresh: called afterwards without them (the views follow).

    """

    def __init__(
        self,
        current: Callable[[], Replay],
        scene_lock: AbstractContextManager[Any],
        show: Callable[[], None],
        refresh: Callable[[], None],
    ) -> None:
        """Start the worker's thread (it waits for requests)."""
        super().__init__()
        self._current = current
        self._scene_lock = scene_lock
        self._show = show
        self._refresh = refresh
        self._limit = RateLimit(1.0)
        #: the latest figures of each map, and what they were computed for
        self.figures: dict[MapMode, MapFigures] = {}
        self.keys: dict[MapMode, tuple[int, ...]] = {}
        #: bumped whenever figures change (views compare it with what they showed)
        self.version = 0
        self.links: LinkJudgement = NO_LINKS  # the log's links and the truth's verdicts
        self.false_key: tuple[int, int] | None = None
        self._todo: set[MapMode] = set()
        self._start("cogmap-figures")

    def get(self, mode: MapMode) -> MapFigures | None:
        """The latest figures of map ``mode`` (None before any)."""
        return self.figures.get(mode)

    def request(self, forced: bool, modes: tuple[MapMode, ...]) -> None:
        """Ask for the accuracy figures of the maps (1 Hz; at once for rebuilt maps ``modes``)."""
        if forced:
            todo: tuple[MapMode, ...] = modes
        elif self._limit.due():
            todo = ALL_MODES
        else:
            return
        with self._cond:
            self._todo.update(todo)
            self._cond.notify()

    def forget(self) -> None:
        """Drop every figure (another input is replayed; call with both locks held)."""
        self.figures.clear()
        self.keys.clear()
        self.false_key = None
        self.links = NO_LINKS

    def _pending(self) -> bool:
        return bool(self._todo)

    def _take(self) -> list[MapMode]:
        """Every map asked for, in :data:`ALL_MODES`'s order."""
        todo = [m for m in ALL_MODES if m in self._todo]
        self._todo.clear()
        return todo

    def _work_on(self, work: list[MapMode]) -> None:
        self._compute(work)

    def _compute(self, modes: list[MapMode]) -> None:
        """Compute the figures of ``modes`` that changed, holding the replay lock only to copy.

        The inputs (the maps' snapshots, a copy of the log for the false links) are taken under
        the lock; the computation (some 30 ms per map) runs without it, so playback and rebuilds
        do not wait for it. The results are stored and the scene republished under the lock
        (a paused replay publishes nothing else); the views then refresh, each taking the lock
        for what it reads. Figures of a replay that was swapped for another bag meanwhile are
        dropped; those of a map that changed meanwhile are computed again next round.
        """
        replay = self._current()
        todo: list[tuple[MapMode, tuple[int, ...], FigureInputs]] = []
        with replay.lock:
            if replay is not self._current():
                return
            log_ = replay.session.log
            judging = replay.session.evaluation
            false_key = (id(log_), log_.frames)
            false_inputs = false_link_inputs(log_) if false_key != self.false_key else None
            for mode in modes:
                cmap = replay.session.maps[mode]
                mkey = (id(cmap), cmap.num_vertices, cmap.num_edges, len(cmap.optimizations),
                        log_.frames)  # fmt: skip
                if self.keys.get(mode) != mkey or false_inputs is not None:
                    todo.append((mode, mkey, figure_inputs(log_, cmap)))
        links = self.links if false_inputs is None else judge_links(false_inputs, judging)
        computed = [
            (mode, mkey, compute_figures(inputs, judging, links)) for mode, mkey, inputs in todo
        ]
        if false_inputs is None and not computed:
            return
        with replay.lock, self._scene_lock:
            if replay is not self._current():
                return
            if false_inputs is not None:
                self.false_key = false_key
                self.links = links
            for mode, mkey, figures in computed:
                self.keys[mode] = mkey
                self.figures[mode] = figures
                self.version += 1
            self._show()  # the truth's alignment, the false loop closures; the counters
        self._refresh()
