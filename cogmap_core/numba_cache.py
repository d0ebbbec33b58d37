"""Where numba caches compiled code (the compiled replay's and the front end's loops).

``NUMBA_CACHE_DIR`` when set; else numba's own choice (``__pycache__`` beside the source) when
that is writable; else ``$XDG_CACHE_HOME/cogmap/numba`` or ``~/.cache/cogmap/numba``; caching is
off when none of them is writable.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Callable, MutableMapping
from pathlib import Path
from typing import Any


def writable_folder(folder: Path) -> bool:
    """Whether files can be created in ``folder`` (made if missing)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".cogmap-probe-"):
            pass
    except OSError:
        return False
    return True


def choose_cache(
    source_dir: Path,
    env: MutableMapping[str, str],
    numba_imported: bool,
    home: Path,
    writable: Callable[[Path], bool] = writable_folder,
) -> bool:
    """Choose where numba caches compiled code (module doc); False: no cache at all.

    ``source_dir`` is numba's own choice (``__pycache__`` beside this file); ``env`` the
    environment, where ``NUMBA_CACHE_DIR`` is set to the user cache when that is the writable
    one -- numba reads it once, at import, so only while ``numba_imported`` is False. ``home``:
    the user's home folder (for ``~/.cache`` when ``XDG_CACHE_HOME`` is not set);
    ``writable``: whether a folder can be written (made when missing).
    """
    if env.get("NUMBA_CACHE_DIR"):
        return True
    if writable(source_dir):
        return True
    base = env.get("XDG_CACHE_HOME") or str(home / ".cache")
    user = Path(base) / "cogmap" / "numba"
    if not numba_imported and writable(user):
        env["NUMBA_CACHE_DIR"] = str(user)
        return True
    return False  # nowhere to write (or numba already set up otherwise): compile every time


def cached_njit(source_file: str) -> Any:
    """``numba.njit`` caching where :func:`choose_cache` says, for the loops of ``source_file``.

    Raises:
        ImportError: numba is not installed.

    """
    cache = choose_cache(
        Path(source_file).resolve().parent / "__pycache__",
        os.environ,
        "numba" in sys.modules,
        Path(os.path.expanduser("~")),
    )
    import numba

    return numba.njit(cache=cache)


__all__ = ["cached_njit", "choose_cache", "writable_folder"]
