"""How often the page sends what changes often (the map, counters, images, figures)."""

from __future__ import annotations

import math
import time


class RateLimit:
    """At most ``hz`` times a second: :meth:`due` says whether now is one of them."""

    def __init__(self, hz: float) -> None:
        """A limit of ``hz`` per second (0 or less: no limit)."""
        self.period = 1.0 / hz if hz > 0 else 0.0
        self.last = -math.inf

    def due(self, forced: bool = False) -> bool:
        """Whether to send now (``forced``: yes, and the period starts again)."""
        now = time.monotonic()
        if forced or now - self.last >= self.period:
            self.last = now
            return True
        return False
