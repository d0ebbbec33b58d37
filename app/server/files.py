"""The server's files a visitor reaches: the export folder the page writes, the data folders.

A visitor never names a path on the server. The page writes only into the **export folder**
(``cogmap serve --export-dir DIR``, default ``$COGMAP_CACHE/exports``), under a file name made
safe by :func:`safe_name` (letters, digits, ``.``, ``_``, ``-``; no folders), and never creates
a folder other than the export folder itself. A file in the way is replaced only when it is a
regular file that starts like a cogmap replay (the first :data:`HEAD_BYTES` are read, never the
whole file), and the folder holds at most :data:`MAX_EXPORTS` replays.

"Open another bag or log" offers the bags and logs of the **data folders** (``--data-dir``,
repeatable; default the served input's folder) in a list the server makes
(:meth:`DataFolders.listing`): regular files only (``lstat``: a FIFO, a device or a socket is
never listed, nor opened), with a bag's suffix or a ROS 1 bag's first bytes, or logs of
odometry and place recognition as ``cogmap serve FILE`` takes them -- a ``.txt`` file whose
first data line is a TUC input line (``odom2`` or ``loop``; not its ground truth), an
``*_odometry.csv`` file of CSV rows (its loops and ground truth are found beside it), the first
:data:`HEAD_BYTES` read -- or camera-only inputs: a video (its suffix one of
:data:`~cogmap_core.datasets.video_reader.VIDEO_SUFFIXES`), a folder below a data folder that
holds images (:data:`~cogmap_core.datasets.image_folder.IMAGE_SUFFIXES`), all of them regular
files (a folder with a linked image is not listed) -- up to :data:`MAX_DEPTH` folders deep; a
symbolic link is followed only to a regular file inside the same data folder. A choice is
checked again when it is opened (still a regular file inside the folder, at most
:data:`MAX_BAG_BYTES`; an image folder still a folder of such images), and it is then opened by
its resolved path. Whatever is not in the list -- a path that does not exist,
one outside the folders, a folder -- gets the same answer, and messages shown on the page name
files relative to their data folder (:meth:`Scrubber.scrub`), never by an absolute path.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from cogmap_core.datasets.cache import cache_dir
from cogmap_core.datasets.image_folder import IMAGE_SUFFIXES
from cogmap_core.datasets.video_reader import VIDEO_SUFFIXES
from cogmap_core.errors import InputFileError, OutputError
from cogmap_core.fileio import check_writable, output_error
from cogmap_core.sources.log_text import BOM
from cogmap_core.sources.odometry_csv import looks_like_csv
from cogmap_core.sources.tuc import INPUT_FIELDS

#: What an exported replay starts with (in its ``<head>``); a file in the way without it is
#: never replaced.
REPLAY_MARKER = '<meta name="generator" content="cogmap replay">'
#: How much of a file in the way is read to find :data:`REPLAY_MARKER`.
HEAD_BYTES = 64 * 1024
#: The most replays the export folder may hold before new names are refused.
MAX_EXPORTS = 200
#: The longest file name the page writes.
MAX_NAME = 80

#: Suffixes of the bags listed (ROS 1 bags of other names are recognised by their first bytes).
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
_ROS1_MAGIC = b"#ROSBAG V2.0\n"
#: Folder levels searched below each data folder.
MAX_DEPTH = 3
#: The most bags listed, and folder entries looked at, per listing.
MAX_LISTED = 500
MAX_SCANNED = 20_000
#: The largest bag opened from the page (bytes).
MAX_BAG_BYTES = 256 * 1024**3

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
#: An absolute path left in a message after the known folders were named (``/a/b``).
_ABSOLUTE = re.compile(r"(?<![\w.~-])/(?:[^\s/:;,'\"()\[\]<>]+/)*[^\s/:;,'\"()\[\]<>]+")


def default_export_dir() -> Path:
    """Where the page's exports go unless told: ``$COGMAP_CACHE/exports``."""
    return cache_dir() / "exports"


def safe_name(typed: str, suffix: str = ".html", default: str = "cogmap-replay.html") -> str:
    """A file name for the export folder from what a visitor typed.

    Everything but letters, digits, ``.``, ``_`` and ``-`` becomes ``_`` (so ``/``, ``~`` and
    ``..`` cannot name another folder), leading dots and underscores are dropped (no hidden
    files), the name is cut to :data:`MAX_NAME` characters and ends in ``suffix``:
    ``/etc/cron.d/x.html`` becomes ``etc_cron.d_x.html``.
    """
    name = _UNSAFE.sub("_", typed.strip()).lstrip("._-")
    stem = name[: -len(suffix)] if name.lower().endswith(suffix) else name
    stem = stem.rstrip("._-")[: MAX_NAME - len(suffix)].rstrip("._-")
    return f"{stem}{suffix}" if stem else default


def read_head(path: Path, size: int = HEAD_BYTES) -> bytes | None:
    """The first ``size`` bytes of ``path`` if it is a regular file (not followed if a link)."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        return os.read(fd, size)
    finally:
        os.close(fd)


def is_cogmap_replay(path: Path) -> bool:
    """Whether ``path`` is a regular file starting like a replay cogmap exported."""
    head = read_head(path)
    return head is not None and REPLAY_MARKER.encode() in head


class ExportFolder:
    """The one folder the page writes into (module doc)."""

    def __init__(self, path: Path) -> None:
        """Write into ``path`` (created, with its parents, when first written)."""
        self.path = Path(path).expanduser().absolute()

    def target(self, typed: str, suffix: str = ".html") -> Path:
        """Where a file the visitor named ``typed`` goes: the export folder / a safe name."""
        return self.path / safe_name(typed, suffix)

    def prepare(self, target: Path) -> None:
        """Check that ``target`` (in this folder) may be written now, before any work.

        Raises:
            OutputError: the folder cannot be made or written, or holds too many replays.
            InputFileError: something else than a cogmap replay is in the way.

        """
        assert target.parent == self.path, target
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise output_error(self.path, exc, "create") from None
        check_writable(self.path)
        try:
            existing = os.lstat(target)
        except FileNotFoundError:
            existing = None
        except OSError as exc:
            raise output_error(target, exc) from None
        if existing is not None:
            if not stat.S_ISREG(existing.st_mode) or not is_cogmap_replay(target):
                raise InputFileError(
                    f"{target.name} exists in the export folder and is not a cogmap replay; "
                    "choose another name"
                )
            return
        if self.count(target.suffix) >= MAX_EXPORTS:
            raise OutputError(
                f"the export folder holds {MAX_EXPORTS} replays already; remove some or reuse "
                "a name"
            )

    def count(self, suffix: str) -> int:
        """How many files ending in ``suffix`` the folder holds."""
        try:
            with os.scandir(self.path) as entries:
                return sum(1 for e in entries if e.name.lower().endswith(suffix))
        except OSError:
            return 0


@dataclass(frozen=True, slots=True)
class DataFile:
    """An input the page may open: its ``name`` on the page, where it is, its kind."""

    name: str
    path: Path
    folder: Path  # the data folder's real path
    kind: str = "bag"  # bag, video, images, tuc or csv (cogmap_core.sources.detect.KINDS)


class DataFolders:
    """The folders whose bags the page lists (module doc)."""

    def __init__(self, folders: Sequence[Path]) -> None:
        """List bags below ``folders`` (folders that do not exist list nothing)."""
        self.folders: list[tuple[str, Path, Path]] = []  # (prefix on the page, given, real)
        names: set[str] = set()
        for given in folders:
            given = Path(given).expanduser()
            real = Path(os.path.realpath(given))
            if any(real == r for _, _, r in self.folders):
                continue
            label = real.name or "data"
            while label in names:
                label += "_"
            names.add(label)
            self.folders.append((label, given, real))
        if len(self.folders) == 1:  # one folder: its files by their relative paths
            self.folders = [("", self.folders[0][1], self.folders[0][2])]

    def listing(self) -> list[DataFile]:
        """The bags of the data folders, by name (at most :data:`MAX_LISTED`)."""
        found: list[DataFile] = []
        budget = [MAX_SCANNED]
        for label, _, real in self.folders:
            for relative, path, kind in _walk(real, real, 0, budget):
                name = f"{label}/{relative}" if label else relative
                found.append(DataFile(name, path, real, kind))
                if len(found) >= MAX_LISTED:
                    return sorted(found, key=lambda f: f.name)
        return sorted(found, key=lambda f: f.name)

    def check(self, chosen: DataFile) -> DataFile:
        """``chosen`` again, as it is now: a regular file inside its folder, not too large.

        An image folder: a folder inside it still, of images that are regular files.

        Raises:
            InputFileError: it is not (any more); the message names it as the page does.

        """
        real = Path(os.path.realpath(chosen.path))
        if not _inside(real, chosen.folder):
            raise InputFileError(f"{chosen.name} is no longer inside its data folder")
        if chosen.kind == "images":
            try:
                with os.scandir(real) as scan:
                    images = _holds_images(list(scan))
            except OSError:
                images = False
            if not images:
                raise InputFileError(f"{chosen.name} is not a folder of images any more")
            return DataFile(chosen.name, real, chosen.folder, chosen.kind)
        try:
            info = os.stat(real)
        except OSError:
            raise InputFileError(f"{chosen.name} is gone from the data folder") from None
        if not stat.S_ISREG(info.st_mode):
            raise InputFileError(f"{chosen.name} is not a regular file any more; not opened")
        if info.st_size > MAX_BAG_BYTES:
            raise InputFileError(
                f"{chosen.name} has {info.st_size / 1e9:,.1f} GB, more than the "
                f"{MAX_BAG_BYTES / 1024**3:.0f} GiB a bag opened from the page may have"
            )
        return DataFile(chosen.name, real, chosen.folder, chosen.kind)

    def shown(self, path: str | Path) -> str:
        """How the page names the file ``path``: relative to its data folder, else its name."""
        real = Path(os.path.realpath(path)) if str(path) else Path()
        for label, _, folder in self.folders:
            if _inside(real, folder) and real != folder:
                relative = real.relative_to(folder).as_posix()
                return f"{label}/{relative}" if label else relative
        return Path(path).name

    def scrubber(self, export: ExportFolder | None = None) -> Scrubber:
        """What rewrites messages for the page (data folders and the export folder named)."""
        known: list[tuple[str, str]] = []
        for label, given, real in self.folders:
            for form in {str(real), str(given.absolute()), str(given)}:
                if form not in (".", ""):
                    known.append((form + os.sep, f"{label}/" if label else ""))
                    known.append((form, f"data folder {label}".strip()))
        if export is not None:
            known.append((str(export.path) + os.sep, ""))
            known.append((str(export.path), "the export folder"))
        return Scrubber(known)


class Scrubber:
    """Rewrites a message for the page: known folders by their names, other paths hidden."""

    def __init__(self, known: Sequence[tuple[str, str]]) -> None:
        """Replace each ``(path, shown)`` (longest path first), then any absolute path left."""
        self.known = sorted(known, key=lambda pair: -len(pair[0]))

    def scrub(self, text: str) -> str:
        """``text`` with no absolute server path in it."""
        for path, shown in self.known:
            if path and path in text:
                text = text.replace(path, shown)
        return _ABSOLUTE.sub("<server path>", text)


def _inside(path: Path, folder: Path) -> bool:
    try:
        return os.path.commonpath([path, folder]) == str(folder)
    except ValueError:
        return False


def _walk(
    root: Path, folder: Path, depth: int, budget: list[int]
) -> Iterator[tuple[str, Path, str]]:
    """``(relative name, real path, kind)`` of the inputs below ``folder`` (module doc)."""
    try:
        with os.scandir(folder) as scan:
            entries = sorted(scan, key=lambda e: e.name)
    except OSError:
        return
    if depth > 0 and _holds_images(entries):
        yield str(folder.relative_to(root)), folder, "images"
    for entry in entries:
        budget[0] -= 1
        if budget[0] < 0:
            return
        if entry.name.startswith("."):
            continue
        path = Path(entry.path)
        try:
            if entry.is_symlink():
                real = Path(os.path.realpath(path))
                if not _inside(real, root) or not stat.S_ISREG(os.stat(real).st_mode):
                    continue  # (links to folders are not followed either)
            elif entry.is_dir(follow_symlinks=False):
                if depth < MAX_DEPTH:
                    yield from _walk(root, path, depth + 1, budget)
                continue
            elif stat.S_ISREG(entry.stat(follow_symlinks=False).st_mode):
                real = path
            else:
                continue  # a FIFO, a device, a socket: never listed, never opened
        except OSError:
            continue
        if real.suffix.lower() in IMAGE_SUFFIXES:
            continue  # (their folder is listed)
        if real.suffix.lower() in BAG_SUFFIXES or _is_ros1_bag(real):
            yield str(path.relative_to(root)), real, "bag"
        elif real.suffix.lower() in VIDEO_SUFFIXES:
            yield str(path.relative_to(root)), real, "video"
        else:
            kind = _log_kind(real)
            if kind is not None:
                yield str(path.relative_to(root)), real, kind


def _holds_images(entries: Sequence[os.DirEntry[str]]) -> bool:
    """Whether a folder's ``entries`` hold an image, every image a regular file (no link)."""
    images = [e for e in entries if Path(e.name).suffix.lower() in IMAGE_SUFFIXES]
    try:
        return bool(images) and all(
            not e.is_symlink() and e.is_file(follow_symlinks=False) for e in images
        )
    except OSError:
        return False


def _log_kind(path: Path) -> str | None:
    """``tuc`` or ``csv`` for a log ``cogmap serve`` takes (module doc), else None."""
    name = path.name.lower()
    if not (name.endswith(".txt") or name.endswith("_odometry.csv")):
        return None
    head = read_head(path)
    if head is None:
        return None
    for raw in head.removeprefix(BOM).decode("utf-8", errors="replace").splitlines()[:200]:
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if name.endswith(".txt"):
            return "tuc" if line.split()[0] in INPUT_FIELDS else None
        return "csv" if looks_like_csv(line) else None
    return None


def _is_ros1_bag(path: Path) -> bool:
    head = read_head(path, len(_ROS1_MAGIC))
    return head == _ROS1_MAGIC
