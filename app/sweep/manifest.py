"""The sweep folder: its file names, its manifest (``sweep.json``) and its lock.

A sweep folder is resumed by the same command: :func:`locked_folder` accepts only a folder of
the same sweep (the digest of its cells), and :func:`manifest_bag_records` gives back what an
earlier run recorded of each bag.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from app.events_cache import EVENTS_DIR
from app.sweep.errors import SweepError
from cogmap_core.fileio import write_bytes_atomic

try:  # POSIX advisory locks: one sweep writes a folder at a time
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

SWEEP_FORMAT = "cogmap-sweep"
SWEEP_VERSION = 1

RESULTS_FILE = "results.csv"
MANIFEST_FILE = "sweep.json"
BEST_FILE = "best.json"
PARETO_FILE = "pareto.png"
LOCK_FILE = ".sweep.lock"


def _json_clean(value: Any) -> Any:
    """NaN and infinities become ``None`` (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_clean(v) for v in value]
    return value


def write_json(path: Path, payload: Mapping[str, Any]) -> None:
    """Write strict JSON atomically."""
    text = json.dumps(_json_clean(dict(payload)), indent=2, allow_nan=False) + "\n"
    write_bytes_atomic(path, text.encode())


def manifest_bag_records(manifest: object) -> dict[str, dict[str, Any]]:
    """The per-bag records of a parsed ``sweep.json``, by bag key (``{}`` if there are none)."""
    bags = manifest.get("bags") if isinstance(manifest, dict) else None
    if not isinstance(bags, list):
        return {}
    return {
        str(record["key"]): record
        for record in bags
        if isinstance(record, dict) and "key" in record
    }


@contextlib.contextmanager
def locked_folder(out: Path, digest: str) -> Iterator[dict[str, Any] | None]:
    """Check ``out`` is the folder of the sweep ``digest`` (or new) and lock it.

    Yields the folder's parsed ``sweep.json`` (``None`` for a new folder) while holding the
    folder's lock (``.sweep.lock``): one sweep writes a folder at a time.

    Raises:
        SweepError: ``out`` is a file, a folder of something else or of another sweep, or
            another sweep is writing it.

    """
    previous: dict[str, Any] | None = None
    if out.exists() and not out.is_dir():
        raise SweepError(f"{out} exists and is not a folder; choose another --out")
    manifest = out / MANIFEST_FILE
    if out.is_dir() and any(out.iterdir()):
        if not manifest.exists():
            ours = {EVENTS_DIR, LOCK_FILE}
            if any(p.name not in ours for p in out.iterdir()):
                raise SweepError(f"{out} is not empty and holds no sweep; choose another --out")
        else:
            try:
                previous = json.loads(manifest.read_text())
            except (OSError, ValueError):
                raise SweepError(f"{manifest} is not readable JSON; choose another --out") from None
            if (
                not isinstance(previous, dict)
                or previous.get("format") != SWEEP_FORMAT
                or previous.get("digest") != digest
            ):
                raise SweepError(
                    f"{out} holds another sweep (other settings, bags, map or bag "
                    "contents); choose another --out, or re-run that sweep's own command"
                )
    out.mkdir(parents=True, exist_ok=True)
    handle = (out / LOCK_FILE).open("a")
    try:
        if fcntl is not None:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise SweepError(
                    f"another cogmap sweep is writing {out}; wait for it or choose another --out"
                ) from None
        yield previous
    finally:
        handle.close()
