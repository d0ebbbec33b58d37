"""What every reader of an input shares: it is a context manager that closes the input.

The bag reader (:class:`~cogmap_core.datasets.rosbag_reader.BagReader`), the camera readers
(:class:`~cogmap_core.datasets.camera_common.CameraReader`: videos, image folders) and the log
reader (:class:`~cogmap_core.sources.log_reader.LogReader`) are used as
``with open_source(...) as reader:``. Leaving the block calls :meth:`InputReader.close`, whether
it ends normally or by an exception. Only the bag reader has something to release (the bag's
file, a temporary folder) and overrides it; a log is read into memory at once, and a camera
input opens its files anew for each pass.
"""

from __future__ import annotations

from types import TracebackType
from typing import Self


class InputReader:
    """Base of the input readers: ``with reader:`` closes it at the end (module doc)."""

    def close(self) -> None:
        """Release the input (idempotent); here nothing is held, a reader that holds overrides."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


__all__ = ["InputReader"]
