"""A report folder written safely: staged beside or inside its target, moved into place when done.

:class:`ReportFolder` is the writing side of ``cogmap run``:

- :meth:`~ReportFolder.prepare` runs **before** the bag is processed: it refuses a target that is
  a file, a non-empty folder without ``force``, or a folder holding a sub-folder under one of the
  report's file names, and it creates the staging folder, which proves the target writable;
- the report's files are written into the staging folder (:meth:`~ReportFolder.path`);
- :meth:`~ReportFolder.commit` moves them into place; the completion marker
  :data:`MARKER` (the list of the report's files) is written last.

If the target does not exist, the staging folder is ``.<DIR>.partial-<pid>`` beside it and is
renamed to ``DIR`` in one step. If it exists (empty, or with ``force``), the staging folder is
``DIR/.cogmap-report.partial-<pid>`` (same file system) and only the report's own file names are
replaced, one ``os.replace`` each; files the previous report listed in its marker but the new one
does not write are removed; nothing else in ``DIR`` is touched. Ctrl-C is held back during the
commit. On any failure or interruption before it, the staging folder is deleted and ``DIR`` is
left exactly as it was. Leftovers of killed runs are removed by the next run into the same place.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO

from cogmap_core.errors import OutputError
from cogmap_core.fileio import (
    check_writable,
    describe_os_error,
    interrupts_deferred,
    loads_json,
    output_error,
    partial_name,
    remove_stale,
)

#: Completion marker of a report folder: JSON ``{"cogmap_report": 1, "files": [...]}``.
MARKER = ".cogmap-report"
_STAGING_NAME = "cogmap-report"


def read_marker(folder: Path) -> list[str] | None:
    """The file names listed by the report marker in ``folder``; None without a valid marker."""
    try:
        data = loads_json((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    files = data.get("files") if isinstance(data, dict) else None
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return None
    return [f for f in files if f and "/" not in f and f not in (".", "..")]


class ReportFolder:
    """Stage a report's files and move them into ``out_dir`` when all are written.

    Args:
        out_dir: the report folder (``--out``).
        names: the file names the report may write (checked before any work).
        force: allow an existing non-empty folder; only the report's names are replaced.

    """

    def __init__(self, out_dir: Path, names: Sequence[str], force: bool = False) -> None:
        """Describe the target; nothing is checked or created until :meth:`prepare`."""
        self.out_dir = Path(os.path.abspath(out_dir))
        self.names = tuple(names)
        self.force = force
        self.staging: Path | None = None
        self.written: list[str] = []
        self._merge = False
        self._created: list[Path] = []  # parent folders we made (removed again on failure)

    # ------------------------------------------------------------------ before the work
    def prepare(self) -> None:
        """Check the target and create the staging folder (before any processing).

        Raises:
            OutputError: the target is a file, is not empty (without ``force``), holds a folder
                named like a report file, or cannot be written.

        """
        out = self.out_dir
        if out.exists() or out.is_symlink():
            if not out.is_dir():
                raise OutputError(f"{out} exists and is not a folder; choose another --out")
            self._merge = True
            remove_stale(out, f".{_STAGING_NAME}.partial-*")
            if not self.force and any(out.iterdir()):
                raise OutputError(
                    f"{out} is not empty; choose another --out, or pass --force to replace the "
                    "report's files in it (nothing else in it is touched)"
                )
            for name in (*self.names, MARKER):
                target = out / name
                if target.is_dir() and not target.is_symlink():
                    raise OutputError(
                        f"{target} is a folder; --force replaces only the report's files, so move "
                        "it away or choose another --out"
                    )
            staging = out / partial_name(_STAGING_NAME)
            folder = out
        else:
            folder = out.parent
            self._make_parents(folder)
            remove_stale(folder, f".{out.name}.partial-*")
            staging = folder / partial_name(out.name)
        try:
            if staging.exists():  # our own pid, reused after a killed run
                shutil.rmtree(staging)
            staging.mkdir()
        except OSError as exc:
            self._remove_parents()
            raise output_error(folder, exc, "write in") from None
        self.staging = staging
        try:
            check_writable(staging)
        except OutputError:
            self.discard()
            raise

    def _make_parents(self, folder: Path) -> None:
        missing: list[Path] = []
        probe = folder
        while not probe.exists() and probe != probe.parent:
            missing.append(probe)
            probe = probe.parent
        if probe.exists() and not probe.is_dir():
            raise OutputError(f"{probe} is not a folder; choose another --out")
        for path in reversed(missing):
            try:
                path.mkdir()
            except FileExistsError:
                continue
            except OSError as exc:
                self._remove_parents()
                raise output_error(path, exc, "create") from None
            self._created.append(path)

    def _remove_parents(self) -> None:
        for path in reversed(self._created):
            with contextlib.suppress(OSError):
                path.rmdir()  # only if still empty
        self._created = []

    # ------------------------------------------------------------------ writing
    def path(self, name: str) -> Path:
        """Where to write the report file ``name`` (in the staging folder)."""
        if self.staging is None:
            raise RuntimeError("ReportFolder.prepare() was not called")
        if name not in self.written:
            self.written.append(name)
        return self.staging / name

    @contextlib.contextmanager
    def open(self, name: str, newline: str | None = None) -> Iterator[IO[str]]:
        """Open the report file ``name`` for writing text (UTF-8)."""
        with self.path(name).open("w", encoding="utf-8", newline=newline) as handle:
            yield handle

    def write_text(self, name: str, text: str) -> None:
        """Write the report file ``name`` (UTF-8 text)."""
        self.path(name).write_text(text, encoding="utf-8")

    @contextlib.contextmanager
    def writing(self) -> Iterator[None]:
        """Turn a failed write (full disk, read-only folder...) into a one-line OutputError."""
        try:
            yield
        except OSError as exc:
            kept = "it was left as it was" if self._merge else "nothing was written"
            raise OutputError(
                f"cannot write the report {self.out_dir}: {describe_os_error(exc)}; {kept}"
            ) from None

    # ------------------------------------------------------------------ finishing
    def commit(self) -> list[Path]:
        """Move the written files into ``out_dir`` (marker last); returns their final paths.

        Raises:
            OutputError: the files could not be moved into place.

        """
        staging = self.staging
        if staging is None:
            raise RuntimeError("ReportFolder.prepare() was not called")
        out = self.out_dir
        with self.writing():
            self._sync_files(staging)
            marker = staging / MARKER
            marker.write_text(
                json.dumps({"cogmap_report": 1, "files": self.written}, indent=2) + "\n",
                encoding="utf-8",
            )
        with interrupts_deferred():
            try:
                if self._merge:
                    self._merge_into(out, staging)
                else:
                    os.rename(staging, out)
            except OSError as exc:
                self.discard()
                raise OutputError(
                    f"cannot move the report into {out}: {describe_os_error(exc)}; "
                    "its files may be incomplete (no .cogmap-report marker)"
                ) from None
        self.staging = None
        self._created = []
        return [out / name for name in self.written]

    def _merge_into(self, out: Path, staging: Path) -> None:
        previous = read_marker(out) or []
        (out / MARKER).unlink(missing_ok=True)  # incomplete until the new marker is in place
        for name in self.written:
            os.replace(staging / name, out / name)
        for name in previous:  # the marker is only a file: trust it for our own names only
            if name in self.names and name not in self.written and (out / name).is_file():
                (out / name).unlink()
        os.replace(staging / MARKER, out / MARKER)
        staging.rmdir()

    @staticmethod
    def _sync_files(staging: Path) -> None:
        for path in staging.iterdir():
            if path.is_file():
                fd = os.open(path, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)

    def discard(self) -> None:
        """Delete the staging folder and any parent folder made for it; ``out_dir`` is untouched."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
        self._remove_parents()

    def __enter__(self) -> ReportFolder:
        self.prepare()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self.staging is not None:  # not committed: an error or an interruption
            self.discard()
