"""What the replay worker is doing, as the page and the benchmarks read it.

:class:`PlaybackState` is the worker's state; a :class:`RebuildRecord` times one parameter change
(:attr:`app.server.replay.Replay.rebuilds`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams


class PlaybackState(StrEnum):
    """What the worker is doing."""

    LOADING = "loading"
    PLAYING = "playing"
    PAUSED = "paused"
    ENDED = "ended"
    ERROR = "error"


@dataclass
class RebuildRecord:
    """Timing of one parameter rebuild (for the latency benchmark and the page's log).

    Attributes:
        params: the parameters rebuilt for.
        frames: frames replayed from the cache.
        requested: ``time.perf_counter()`` when the parameters were requested.
        compute_s: rebuild time of each map (s).
        published: ``time.perf_counter()`` when each map was handed to the listener.
        how: per map, ``"built"``, ``"cached"`` (built before for these parameters), ``"kept"``
            (the change does not affect it, or gives it the same cluster schedule).
        resumed: per map built, the events it did not replay again: it continued from the state
            kept at the last cluster close its schedule shares with the map built before
            (:class:`~app.server.rebuild.Checkpoints`); 0 when built from the first event.
        completed: all maps rebuilt (False: abandoned for newer parameters).
        previewed: ``time.perf_counter()`` when a preview of a map was handed to the listener
            (:mod:`app.server.preview`; only maps whose rebuild is slow, before their exact map).
        preview_difference: per previewed map whose exact map arrived, how far the preview was
            from it: (largest vertex shift in m, the preview's vertices minus the exact map's;
            :func:`~app.server.preview.preview_difference`).

    """

    params: MapParams
    frames: int
    requested: float
    compute_s: dict[MapMode, float] = field(default_factory=dict)
    published: dict[MapMode, float] = field(default_factory=dict)
    how: dict[MapMode, str] = field(default_factory=dict)
    resumed: dict[MapMode, int] = field(default_factory=dict)
    completed: bool = False
    previewed: dict[MapMode, float] = field(default_factory=dict)
    preview_difference: dict[MapMode, tuple[float, int]] = field(default_factory=dict)

    def latency(self, mode: MapMode) -> float | None:
        """Seconds from the request to map ``mode`` being shown (None if it never was)."""
        at = self.published.get(mode)
        return None if at is None else at - self.requested

    def preview_latency(self, mode: MapMode) -> float | None:
        """Seconds from the request to the first map ``mode`` shown: a preview or the exact map.

        (:meth:`latency` when there was no preview; None if neither was shown.)
        """
        at = self.previewed.get(mode)
        return self.latency(mode) if at is None else at - self.requested
