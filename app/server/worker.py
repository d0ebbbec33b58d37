"""The page's worker threads: each waits for what is asked, works on it, and never stops the page.

The accuracy figures (:class:`~app.server.figures_worker.FiguresWorker`) and the routes
(:class:`~app.server.routes.RouteWorker`) are computed on threads of their own, so the replay and
the viewers' callbacks never wait for them. The callbacks only record what they ask for, under
the worker's condition, and notify it; the thread then takes it and works on it without the
condition held. :class:`Worker` is that loop, once: what is asked for, how it is taken and what is
done with it are the subclasses' (:meth:`Worker._pending`, :meth:`Worker._take`,
:meth:`Worker._work_on`).
"""

from __future__ import annotations

import threading
import traceback
from abc import ABC, abstractmethod
from typing import Generic, TypeVar

W = TypeVar("W")


class Worker(ABC, Generic[W]):
    """One daemon thread that waits for asks, takes them and works on them (module doc).

    A subclass calls ``super().__init__()`` first, sets what its asks are kept in, then starts the
    thread with :meth:`_start`. To ask, it updates them under ``self._cond`` and calls
    ``self._cond.notify()``. The thread wakes for an ask or a stop (and looks again every 0.5 s);
    it takes what is asked (:meth:`_take`, with the condition held) and works on it
    (:meth:`_work_on`, without it). An exception there is printed and never stops the thread.
    """

    def __init__(self) -> None:
        """Make the condition and the flags (the thread starts with :meth:`_start`)."""
        self._cond = threading.Condition()
        self._busy = False
        self._stop = False

    def _start(self, name: str) -> None:
        """Start the thread, named ``name``."""
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    @abstractmethod
    def _pending(self) -> bool:
        """Whether anything is asked for (called with ``self._cond`` held)."""

    @abstractmethod
    def _take(self) -> W:
        """Take what is asked for, leaving it asked no more (``self._cond`` held; pending)."""

    @abstractmethod
    def _work_on(self, work: W) -> None:
        """Do the work taken (on the thread, without ``self._cond``)."""

    def idle(self) -> bool:
        """Whether nothing is asked for or under way."""
        with self._cond:
            return not self._pending() and not self._busy

    def stop(self) -> None:
        """Stop the thread after the work under way."""
        with self._cond:
            self._stop = True
            self._cond.notify()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._pending() and not self._stop:
                    self._cond.wait(0.5)
                if self._stop:
                    return
                work = self._take()
                self._busy = True
            try:
                self._work_on(work)
            except Exception:  # the figures or a route must never stop the page
                traceback.print_exc()
            finally:
                with self._cond:
                    self._busy = False


__all__ = ["Worker"]
