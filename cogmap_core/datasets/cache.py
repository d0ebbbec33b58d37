"""The default dataset: generated once into the cache directory, then reused.

The cache directory is ``$COGMAP_CACHE`` if set, else ``$XDG_CACHE_HOME/cogmap``, else
``~/.cache/cogmap``. The default dataset is the iRat-like maze (:data:`DEFAULT_CONFIG`: 6 laps,
seed 1): 825 s (13 min 45 s) of data, 14446 camera frames, 130 m driven, a 168 MB bag, made in
35-50 s on two cores. Its file name carries :data:`DATASET_VERSION`, bumped whenever the
generator's output changes, so a stale cached bag is never used. Generation writes to a
temporary name and renames at the end, under a lock, so concurrent callers wait for one
generation and never see a half-written bag.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from cogmap_core.datasets.errors import DatasetCacheError
from cogmap_core.datasets.generator import MazeConfig, ProgressFn, generate_maze_bag
from cogmap_core.fileio import remove_stale

try:  # POSIX advisory locks; without them concurrent first uses may generate twice
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

CACHE_ENV = "COGMAP_CACHE"
DATASET_VERSION = 4
#: The default dataset's settings (the iRat-like layout, 6 laps).
DEFAULT_CONFIG = MazeConfig()


def cache_dir() -> Path:
    """The dataset cache directory (not created here)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "cogmap"


def default_dataset_name() -> str:
    """File name of the default dataset in the cache."""
    c = DEFAULT_CONFIG
    return f"{Path(c.layout).stem}_{c.laps}laps_seed{c.seed}_v{DATASET_VERSION}.bag"


def default_dataset_file() -> Path:
    """Where the default dataset lives (it may not exist yet)."""
    return cache_dir() / default_dataset_name()


@contextlib.contextmanager
def cache_lock(folder: Path) -> Iterator[None]:
    """Hold the cache folder's lock (``folder/.lock``): one process writes into it at a time.

    Raises:
        DatasetCacheError: the folder cannot be written.

    """
    lock_path = folder / ".lock"
    try:
        handle = lock_path.open("a")
    except OSError as exc:
        raise DatasetCacheError(
            f"cannot write to the dataset cache {folder}: {exc.strerror}; set {CACHE_ENV} to a "
            "writable folder"
        ) from None
    with handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(handle, fcntl.LOCK_UN)


def default_dataset_path(
    progress: ProgressFn | None = None,
    *,
    regenerate: bool = False,
    workers: int | None = None,
) -> Path:
    """Path of the default dataset, generating it first if it is not in the cache.

    Generation takes about a minute on two cores; ``progress(done, total)`` is called with the
    frames rendered so far. Preview pictures are written next to the bag.

    Args:
        progress: progress callback for a generation.
        regenerate: generate again even if the bag exists.
        workers: rendering processes (default: all CPUs).

    Raises:
        DatasetCacheError: the cache directory cannot be created or written.

    """
    path = default_dataset_file()
    folder = path.parent
    remove_stale(folder, f".{path.name}.partial-*")  # of a generation that was killed
    if path.exists() and not regenerate:
        return path
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetCacheError(
            f"cannot create the dataset cache {folder}: {exc.strerror}; set {CACHE_ENV} to a "
            "writable folder"
        ) from None
    with cache_lock(folder):
        if path.exists() and not regenerate:  # another process made it while we waited
            return path
        for stale in folder.glob(f".{path.name}.partial-*"):
            stale.unlink(missing_ok=True)
        generate_maze_bag(
            path,
            DEFAULT_CONFIG,
            overwrite=True,
            preview=True,
            workers=workers,
            progress=progress,
        )
    return path


@dataclass(frozen=True)
class CachedBag:
    """A bag in the cache directory."""

    path: Path
    size_bytes: int
    is_default: bool


def cached_bags() -> list[CachedBag]:
    """The bags in the cache directory (the default one first if present)."""
    folder = cache_dir()
    if not folder.is_dir():
        return []
    default = default_dataset_file()
    bags = [
        CachedBag(p, p.stat().st_size, p == default)
        for p in sorted(folder.glob("*.bag"))
        if p.is_file()
    ]
    return sorted(bags, key=lambda b: not b.is_default)
