"""A minimal terminal progress bar (stderr, throttled, no dependency)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """``[#####.....] 45% 1234/2750 frames  t=70.5 s``, redrawn at most ``rate_hz`` times/s."""

    def __init__(self, label: str, stream: TextIO | None = None, rate_hz: float = 8.0) -> None:
        """Create a bar writing to ``stream`` (default: stderr)."""
        self.label = label
        self.stream = stream or sys.stderr
        self.period = 1.0 / rate_hz
        self._last = 0.0
        self._drawn = False

    def __call__(self, done: int, total: int, data_time: float) -> None:
        """Report progress; redraws when enough time has passed or at the end."""
        self.draw(done, total, f"{done}/{total} frames  t={data_time:7.1f} s")

    def draw(self, done: int, total: int, text: str) -> None:
        """Redraw the bar at ``done / total``, then ``text`` (throttled; always at the end)."""
        now = time.monotonic()
        if now - self._last < self.period and done < total:
            return
        self._last = now
        fraction = min(done / total, 1.0) if total > 0 else 0.0
        filled = int(30 * fraction)
        self.stream.write(
            f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] {fraction * 100:5.1f}% {text}"
        )
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        """End the bar's line."""
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
