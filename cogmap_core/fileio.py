"""Safe file output: atomic writes with normal permissions, writability probes, stale leftovers.

Every file cogmap writes goes through a temporary name in the target's folder and is renamed
into place when complete (:func:`atomic_writer`), so a reader never sees a half-written file and
an interrupted or failed write leaves the previous file intact. Temporary files are created with
mode ``0o666`` minus the umask -- the permissions any other file of the user gets (not the
``0o600`` of :func:`tempfile.mkstemp`).

Temporary names carry the writing process's id (``...partial-<pid>``) so that leftovers of a
killed process can be told from the work of a live one and removed (:func:`remove_stale`).

A command checks its outputs before the work, so that a long run does not fail at its end: a
single output file named by an option goes through :func:`check_output_file`, a folder through
:func:`check_writable` (report folders: ``app/report.py``).
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import secrets
import shutil
import signal
import threading
import zipfile
import zlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import CogmapError, OutputError

_PID_SUFFIX = re.compile(r"\.partial-(\d+)(?:\.[0-9a-f]+)?$")

#: What to do about each kind of write failure (errno -> advice).
_ADVICE = {
    errno.ENOSPC: "the disk is full; free some space or write somewhere else",
    errno.EDQUOT: "the disk quota is exceeded; free some space or write somewhere else",
    errno.EROFS: "the file system is read-only; write somewhere else",
    errno.EACCES: "permission denied; write somewhere else or fix the folder's permissions",
    errno.EPERM: "permission denied; write somewhere else or fix the folder's permissions",
    errno.ENOENT: "the folder does not exist; create it first",
    errno.ENOTDIR: "a part of the path is not a folder; check the path",
    errno.EISDIR: "a folder is in the way; move it or write somewhere else",
}


def describe_os_error(exc: OSError) -> str:
    """A short description of a failed write: the system's reason and what to do."""
    reason = exc.strerror or type(exc).__name__
    advice = _ADVICE.get(exc.errno or 0, "check the folder and the free space")
    return f"{reason} ({advice})"


def output_error(target: Path | str, exc: OSError, what: str = "write") -> OutputError:
    """The one-line :class:`OutputError` for an :class:`OSError` met writing ``target``."""
    return OutputError(f"cannot {what} {target}: {describe_os_error(exc)}")


def pid_alive(pid: int) -> bool:
    """Whether a process with id ``pid`` exists (ours counts as alive)."""
    if pid == os.getpid():
        return True
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    except OSError:
        return False
    return True


def partial_name(name: str, pid: int | None = None) -> str:
    """The hidden temporary name ``.<name>.partial-<pid>`` of ``name`` while it is written."""
    return f".{name}.partial-{os.getpid() if pid is None else pid}"


def remove_stale(folder: Path, pattern: str) -> list[Path]:
    """Delete leftovers of killed processes matching ``pattern`` (a glob) in ``folder``.

    Only names ending in ``.partial-<pid>`` (optionally followed by ``.<hex>``) whose process
    no longer exists are removed (files, or folders with everything in them). Returns what was
    removed; errors are ignored (a leftover that cannot be removed is harmless).
    """
    removed: list[Path] = []
    try:
        candidates = sorted(folder.glob(pattern))
    except OSError:
        return removed
    for path in candidates:
        match = _PID_SUFFIX.search(path.name)
        if match is None or pid_alive(int(match.group(1))):
            continue
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
        except OSError:
            continue
        removed.append(path)
    return removed


def create_file(path: Path, exclusive: bool = True) -> int:
    """Open ``path`` for writing with mode ``0o666`` minus the umask; return the descriptor."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_EXCL if exclusive else os.O_TRUNC)
    flags |= getattr(os, "O_CLOEXEC", 0)
    return os.open(path, flags, 0o666)


def check_writable(folder: Path) -> None:
    """Create and remove a probe file in ``folder``.

    Raises:
        OutputError: the folder is missing, read-only, full or not ours to write.

    """
    probe = folder / f".cogmap-probe-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        fd = create_file(probe)
        try:
            os.write(fd, b"x")
        finally:
            os.close(fd)
        probe.unlink()
    except OSError as exc:
        with contextlib.suppress(OSError):
            probe.unlink()
        raise output_error(folder, exc, "write in") from None


def check_output_file(path: Path, option: str, force: bool) -> None:
    """Refuse a single output file that would fail only at the end of the work.

    The rule of a one-file output named by ``option`` (``--save-session FILE``): a folder in the
    way is refused, an existing file is replaced only with ``force`` (``--force``), and the file's
    folder must exist and be writable (a probe file: mode bits do not stop root).

    Raises:
        OutputError: one line naming the file, the problem and ``option``, and what to do.

    """
    if path.is_dir():
        raise OutputError(f"{path} is a directory; give {option} a file name")
    if path.exists() and not force:
        raise OutputError(
            f"{path} already exists; choose another {option} file or pass --force to overwrite it"
        )
    if not path.parent.is_dir():
        raise OutputError(f"folder {path.parent} of {option} does not exist; create it")
    check_writable(path.parent)


@contextlib.contextmanager
def atomic_writer(
    path: Path, binary: bool = False, newline: str | None = None
) -> Iterator[IO[Any]]:
    """Write ``path`` (UTF-8 text, or bytes if ``binary``) through a temporary file beside it.

    The temporary file ``.<name>.partial-<pid>.<hex>`` gets the user's normal permissions and is
    flushed to disk before the rename. On any exception (including Ctrl-C) it is deleted and
    ``path`` is left as it was; temporary files of ``path`` left by killed processes are
    deleted first.

    Raises:
        OSError: the folder cannot be written (the caller words the message, see
            :func:`output_error`).

    """
    path = Path(path)
    remove_stale(path.parent, f".{path.name}.partial-*")  # a killed writer's leftovers
    tmp = path.with_name(f"{partial_name(path.name)}.{secrets.token_hex(4)}")
    fd = create_file(tmp)
    try:
        if binary:
            handle: IO[Any] = os.fdopen(fd, "wb")
        else:
            handle = os.fdopen(fd, "w", encoding="utf-8", newline=newline)
    except BaseException:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    try:
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_writer`)."""
    with atomic_writer(path, binary=True) as handle:
        handle.write(data)


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_writer`)."""
    with atomic_writer(path) as handle:
        handle.write(text)


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM back while the block runs, then deliver them.

    For short steps that must not be cut in half (moving a finished report into place). Only
    the main thread can install signal handlers; elsewhere the block runs unprotected.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum: int, frame: object) -> None:
        received.append(signum)

    previous: dict[int, object] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        current = signal.getsignal(sig)
        if current is None:  # installed outside Python: leave it alone
            continue
        previous[sig] = current
        signal.signal(sig, hold)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        if received:
            signal.raise_signal(received[0])


#: The largest JSON file cogmap reads (parameter files, front-end profiles, report markers).
MAX_JSON_BYTES = 16 * 1024 * 1024


def loads_json(text: str | bytes) -> Any:
    """``json.loads``, with a document nested deeper than Python's parser goes as a ValueError.

    (The parser raises RecursionError on ``[[[...]]]`` nested some thousands deep.)
    """
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("it is nested too deeply to read") from None


def read_json(
    path: Path, what: str, error: type[CogmapError], max_bytes: int = MAX_JSON_BYTES
) -> Any:
    """The JSON document in file ``path`` (at most ``max_bytes``), or ``error`` in one line.

    ``what`` names the file in messages ("parameter file"). A file larger than ``max_bytes``
    is refused without being read.
    """
    try:
        with path.open("rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if size > max_bytes:
                raise error(
                    f"{path}: the {what} has {size} bytes, more than the "
                    f"{max_bytes // (1024 * 1024)} MiB a {what} may have"
                )
            data = handle.read(max_bytes + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(data) > max_bytes:  # (a file that grew while read)
        raise error(f"{path}: the {what} has more than {max_bytes // (1024 * 1024)} MiB")
    try:
        return loads_json(data)
    except (UnicodeDecodeError, ValueError) as exc:
        raise error(f"{path}: not a readable JSON file ({' '.join(str(exc).split())})") from None


#: The most one of cogmap's archives (a session or event file) may hold, uncompressed (bytes).
#: The session of a 60-lap run (2 h 25 min of data) holds about 25 MB; a file declaring more is
#: refused before any of it is read.
MAX_ARCHIVE_BYTES = 512 * 1024 * 1024
#: The most an archive's JSON header may hold (bytes): a session's is some 60 kB.
MAX_HEADER_BYTES = 32 * 1024 * 1024
#: The most arrays an archive may hold (a session has some 170).
MAX_ARCHIVE_MEMBERS = 4096

HeaderCheck = Callable[[dict[str, Any]], None]


def _megabytes(count: int) -> str:
    return f"{count / 1e6:,.1f} MB"


def _check_members(
    path: Path, archive: zipfile.ZipFile, what: str, error: type[CogmapError]
) -> dict[str, zipfile.ZipInfo]:
    """The archive's arrays by name, once their declared sizes are known to fit the caps.

    Each member's uncompressed size (the zip directory's ``file_size``, which bounds what reading
    it can yield) and the size its ``.npy`` header declares (``shape`` x ``itemsize``, which
    NumPy allocates before it reads) are checked against :data:`MAX_ARCHIVE_BYTES` (the header:
    :data:`MAX_HEADER_BYTES`) before anything is decompressed beyond those headers.
    """
    infos = archive.infolist()
    if len(infos) > MAX_ARCHIVE_MEMBERS:
        raise error(
            f"{path}: the {what} file has {len(infos)} members, more than the "
            f"{MAX_ARCHIVE_MEMBERS} a cogmap {what} file may have; it is not one cogmap wrote"
        )
    members: dict[str, zipfile.ZipInfo] = {}
    total = 0
    for info in infos:
        name = info.filename
        if not name.endswith(".npy") or info.is_dir():
            raise error(f"{path}: not a cogmap {what} file (member {name!r} is not an array)")
        key = name[: -len(".npy")]
        cap = MAX_HEADER_BYTES if key == "header" else MAX_ARCHIVE_BYTES
        total += info.file_size
        if info.file_size > cap or total > MAX_ARCHIVE_BYTES:
            held = "holds" if info.file_size > cap else "brings the file to"
            size = info.file_size if info.file_size > cap else total
            limit = cap if info.file_size > cap else MAX_ARCHIVE_BYTES
            raise error(
                f"{path}: array {key} {held} {_megabytes(size)} uncompressed, more than the "
                f"{limit // (1024 * 1024)} MiB a cogmap {what} file may hold; refused unread"
            )
        with archive.open(info) as handle:
            version = np.lib.format.read_magic(handle)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
            else:
                raise ValueError(f"array {key} has .npy format version {version}")
        if dtype.hasobject:
            raise ValueError(f"array {key} holds Python objects")
        declared = math.prod(int(n) for n in shape) * dtype.itemsize
        if declared > info.file_size:
            raise error(
                f"{path}: array {key} declares {_megabytes(declared)} but holds "
                f"{_megabytes(info.file_size)}; the file is corrupt"
            )
        members[key] = info
    return members


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> NDArray[Any]:
    with archive.open(info) as handle:
        return np.lib.format.read_array(handle, allow_pickle=False)


def load_archive(
    path: Path,
    what: str,
    format_name: str,
    version: int,
    error: type[CogmapError],
    required: Sequence[str] = (),
    advice: str = "",
    version_advice: str = "",
    check_header: HeaderCheck | None = None,
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """Read one of cogmap's ``.npz`` archives: its JSON header and its arrays.

    The archive holds a ``header`` array (a JSON object with ``format`` and ``version``) beside
    the data arrays. ``what`` names the kind in messages ("event" for "no such event file");
    ``advice`` ends the message of an unreadable file, ``version_advice`` that of another version.

    Nothing large is allocated before it is known to fit: the sizes every member declares are
    checked first (:data:`MAX_ARCHIVE_BYTES`, :data:`MAX_HEADER_BYTES`), then the header is
    read and checked (format, version, and ``check_header``, which may refuse the file by
    raising before any array is read), then the arrays.

    Returns:
        The header and the arrays (without the header), all read into memory.

    Raises:
        error: a missing, truncated or corrupt file, a required array missing, a header that is
            not a JSON object of this format, or another version, a file larger than the caps
            (one line naming the problem); whatever ``check_header`` raises.

    """
    if not path.is_file():
        raise error(f"{path}: no such {what} file")
    try:
        with path.open("rb") as handle, zipfile.ZipFile(handle) as archive:
            members = _check_members(path, archive, what, error)
            missing = [name for name in ("header", *required) if name not in members]
            if missing:
                raise error(f"{path}: not a cogmap {what} file (missing {', '.join(missing)})")
            text = str(_read_member(archive, members.pop("header")))
            header = _parse_header(path, text, what, format_name, version, error, version_advice)
            if check_header is not None:
                check_header(header)
            arrays = {name: _read_member(archive, info) for name, info in members.items()}
    except CogmapError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError, zlib.error) as exc:
        raise error(
            f"{path}: not a readable cogmap {what} file ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())}); {advice}"
        ) from None
    except MemoryError:
        raise error(f"{path}: the {what} file does not fit in memory") from None
    return header, arrays


def _parse_header(
    path: Path,
    text: str,
    what: str,
    format_name: str,
    version: int,
    error: type[CogmapError],
    version_advice: str,
) -> dict[str, Any]:
    try:
        header = loads_json(text)
    except ValueError:  # (json.JSONDecodeError is one; so is a header nested too deep)
        raise error(f"{path}: the {what} file's header is not valid JSON; it is corrupt") from None
    found = header.get("format") if isinstance(header, dict) else None
    if found != format_name:
        raise error(f"{path}: not a cogmap {what} file (format {found!r})")
    if header.get("version") != version:
        raise error(
            f"{path}: {what} format version {header.get('version')!r} is not supported "
            f"(this cogmap reads version {version}); {version_advice}"
        )
    return header
