"""The sweep's errors, under one root: :class:`SweepError` (a ``CogmapError``)."""

from __future__ import annotations

from cogmap_core.errors import CogmapError


class SweepError(CogmapError):
    """A sweep cannot start or finish (bad folder, unreachable cluster, failed cells, ...)."""


class FailedCells(SweepError):
    """Every cell has a result, but some failed (their errors are in ``results.csv``)."""


class SchedulerLost(SweepError):
    """The connection to the Dask scheduler was lost during the sweep."""
