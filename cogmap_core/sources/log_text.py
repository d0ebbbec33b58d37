r"""Log text files read into arrays: fast, in bounded memory, with every value's line number.

The readers of :mod:`cogmap_core.sources.tuc` and :mod:`cogmap_core.sources.odometry_csv`
describe their lines with a :class:`LineFormat`; :func:`read_rows` reads a file of them into one
:class:`Rows` per kind of line: a float64 array of the numbers kept and an int array of the line
each row came from (``file:line`` text is made only for a message).

**Bounded memory.** The file is read :data:`BLOCK` bytes of whole lines at a time; a block's lines
are split and their numbers parsed with array operations, and only the kept numbers stay: 8 bytes
per value and 8 per line number, plus a few blocks' worth of work space. A line longer than
:data:`MAX_LINE` bytes is refused (no log has one; a file without line ends is not a log), and so
is a file of more than :data:`MAX_ROWS` rows, before its arrays grow past about 1.6 GB.

**Lines** end at ``\n``, ``\r\n`` or ``\r``. A UTF-8 byte-order mark at the start is skipped;
blanks and tabs around fields, blank lines and comment lines (first field starting with ``#``)
are ignored. A file that is not UTF-8 is refused.

**Two paths, one result.** A line of plain decimal numbers ``[+-]digits[.digits][e[+-]digits]``
(the usual line) is parsed by array code. Any other line -- a CSV header, a number Python reads
in another spelling (``nan``, ``1_000``, non-ASCII digits), an unknown type, a wrong field count,
anything malformed -- goes to the format's reference parser, one line at a time, which applies
the reader's rules with Python's ``float`` and raises the error naming file and line. The array
code computes a value only where it is exact, so both paths give the same bits: the mantissa
(at most 18 digits) is read as an integer and scaled by one correctly rounded multiplication or
division by a power of ten when the mantissa is at most 2**53 and the power at most 22 (Clinger's
fast path, the one ``strtod`` takes); other numbers are read with ``float``.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

BLOCK = 1 << 20
"""Bytes read at a time (then cut back to the last line end)."""
MAX_LINE = 1 << 20
"""The longest line a log may have (bytes)."""
MAX_ROWS = 15_000_000
"""The most rows a file may hold (all kinds together): at 32 bytes a row, kept while the file is
read and once more in the final arrays, reading 10 M rows peaks at about 1.1 GB; past this many a
file is refused (one line naming the line) before its arrays grow beyond about 1.6 GB."""
BOM = b"\xef\xbb\xbf"

_MAX_DIGITS = 18  # mantissa digits read as an int64 (10**18 - 1 < 2**63)
_MAX_EXPONENT_DIGITS = 4
_EXACT_MANTISSA = 2**53
_EXACT_POWER = 22
_POW10 = 10.0 ** np.arange(_EXACT_POWER + 1)


class LogFormatError(InputFileError):
    """A log file has a malformed line or values that break the log's rules (file:line named)."""


def is_number(text: str) -> bool:
    """Whether ``text`` reads as a float (the log readers' test of a field)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Rows:
    """The numbers of one kind of line and the line each row came from.

    Attributes:
        what: what the rows are, for messages (``odometry``, ``loop``, ``ground truth``).
        columns: the column names.
        path: the file.
        values: ``(n, len(columns))`` float64.
        lines: ``(n,)`` 1-based line numbers in ``path``.

    """

    what: str
    columns: tuple[str, ...]
    path: Path
    values: FloatArray
    lines: IntArray

    @classmethod
    def empty(cls, what: str, columns: tuple[str, ...], path: Path) -> Rows:
        """No rows."""
        return cls(what, columns, path, np.zeros((0, len(columns))), np.zeros(0, np.int64))

    def __len__(self) -> int:
        return int(self.lines.shape[0])

    def where(self, row: int) -> str:
        """``file:line`` of row ``row`` (for a message)."""
        return f"{self.path}:{int(self.lines[row])}"

    def take(self, index: IntArray | BoolArray) -> Rows:
        """The rows selected by ``index`` (indices or a mask), in that order."""
        return Rows(self.what, self.columns, self.path, self.values[index], self.lines[index])

    def with_values(self, values: FloatArray, columns: tuple[str, ...] | None = None) -> Rows:
        """The same lines with other values (and columns)."""
        return Rows(self.what, columns or self.columns, self.path, values, self.lines)


@dataclass(frozen=True)
class LineKind:
    """One kind of line of a format.

    Attributes:
        name: the first word naming the kind (TUC: ``odom2``); empty when a file holds one kind.
        what: what its rows are, for messages.
        columns: the names of the kept numbers.
        widths: how many numbers a line may hold.
        keep: which of them are kept, in the order of ``columns``; a kept number past a line's
            width is NaN (a CSV ground truth without a heading).

    """

    name: str
    what: str
    columns: tuple[str, ...]
    widths: tuple[int, ...]
    keep: tuple[int, ...]


Parsed = tuple[int, list[float]] | None
"""What the reference parser makes of a line: ``(kind index, kept numbers)``, or None."""


class Block:
    """One block of whole lines split into tokens (array code, no Python loop per line).

    Attributes:
        a: the bytes.
        ends: per line, the position of its line end (``a.size`` for a last line without one).
        starts: per line, its first byte.
        tstart, tend: per token (a run of bytes that are not blanks, nor commas in CSV), its
            first byte and the byte after it.
        counts: per line, its number of tokens.
        first: per line, the index of its first token (meaningless where ``counts`` is 0).
        odd: per line, whether it must go to the reference parser.
        commas: positions of commas (CSV), or None.
        strange: positions of control characters other than blanks and line ends, and of
            non-ASCII bytes (their lines are odd: Python's rules for them are the reference's).

    """

    def __init__(self, data: bytes, commas: bool) -> None:
        """Split ``data`` (whole lines) into lines and tokens."""
        a = np.frombuffer(data, np.uint8)
        self.a = a
        size = a.size
        # one pass finds line ends, CRs, tabs, control characters and non-ASCII bytes
        special = np.flatnonzero((a - 32) > 94)  # (uint8: printable ASCII is 0..94)
        byte = a[special]
        ends = special[byte == 10]
        cr = special[byte == 13]
        if cr.size:
            after = np.minimum(cr + 1, size - 1)
            lone = cr[(cr + 1 >= size) | (a[after] != 10)]
            if lone.size:
                ends = np.union1d(ends, lone)
        if size and (ends.size == 0 or ends[-1] != size - 1):
            ends = np.append(ends, size)  # the file's last line, without a line end
        self.ends = ends
        self.starts = np.concatenate(([0], ends[:-1] + 1)) if ends.size else ends
        self.strange = special[(byte < 9) | ((byte > 13) & (byte < 32)) | (byte > 126)]
        token = a > 32
        self.commas = None
        if commas:
            comma = a == 44
            self.commas = np.flatnonzero(comma)
            token &= ~comma
        change = np.flatnonzero(token[1:] != token[:-1]) + 1
        if size and token[0]:
            change = np.concatenate(([0], change))
        if size and token[-1]:
            change = np.append(change, size)
        self.tstart = change[0::2]
        self.tend = change[1::2]
        before = np.searchsorted(self.tstart, ends)  # tokens before each line end
        self.first = np.concatenate(([0], before[:-1])) if before.size else before
        self.counts = before - self.first
        self.odd = np.zeros(ends.size, bool)
        self.odd[np.searchsorted(ends, self.strange)] = True

    @property
    def lines(self) -> int:
        """How many lines the block holds."""
        return int(self.ends.size)

    def line_of(self, token: IntArray) -> IntArray:
        """The line of each token in ``token``."""
        return np.searchsorted(self.ends, self.tstart[token])

    def first_bytes(self) -> NDArray[np.uint8]:
        """Per line, the first byte of its first token (0 for a line without tokens)."""
        has = self.counts > 0
        out = np.zeros(self.lines, np.uint8)
        out[has] = self.a[self.tstart[self.first[has]]]
        return out

    def token_is(self, token: IntArray, word: bytes) -> BoolArray:
        """Per token in ``token``, whether it is ``word``."""
        same = self.tend[token] - self.tstart[token] == len(word)
        last = self.a.size - 1
        for j, byte in enumerate(word):
            same &= self.a[np.minimum(self.tstart[token] + j, last)] == byte
        return same

    def blank(self, buf: NDArray[np.uint8], token: IntArray) -> None:
        """Blank out the bytes of the tokens ``token`` in ``buf`` (a copy of the block)."""
        if not token.size:
            return
        length = self.tend[token] - self.tstart[token]
        offset = np.cumsum(length) - length
        buf[
            np.repeat(self.tstart[token] - offset, length) + np.arange(int(offset[-1] + length[-1]))
        ] = 32

    def text(self, line: int) -> str:
        """Line ``line`` of the block (without its line end)."""
        return bytes(self.a[self.starts[line] : self.ends[line]]).decode("utf-8")


class LineFormat:
    """How the lines of one kind of log file are read (subclassed per format)."""

    expected = "log lines"
    """What the lines should be, for the message about a file that is not text."""
    commas = False
    """Fields are separated by commas (CSV), not by blanks (TUC)."""
    kinds: tuple[LineKind, ...] = ()

    def classify(self, block: Block) -> tuple[IntArray, IntArray]:
        """Per line of ``block``: its kind (-1: skip it) and the index of its first number token.

        Lines the array code cannot take are marked in ``block.odd`` (their kind is ignored).
        """
        raise NotImplementedError

    def reference(self, text: str, where: str, first: bool) -> tuple[Parsed, bool]:
        """One line read by the format's rules, and whether it held data (not blank or comment).

        Args:
            text: the line.
            where: its ``file:line``, for the message.
            first: no line before it held data (in CSV, it may be the header).

        Returns:
            ``(kind, kept numbers)`` or None (a line to skip), and whether the line held data.

        Raises:
            LogFormatError: the line is malformed (``where`` names it).

        """
        raise NotImplementedError

    def kept(self, kind: LineKind, values: Sequence[float]) -> list[float]:
        """The kept numbers of a line of ``kind`` holding ``values`` (NaN past its width)."""
        return [values[i] if i < len(values) else float("nan") for i in kind.keep]


def read_rows(path: Path, fmt: LineFormat) -> list[Rows]:
    """Read every line of ``path`` as ``fmt`` says: one :class:`Rows` per kind, in file order.

    Raises:
        InputFileError: a missing or unreadable file.
        LogFormatError: the file is not UTF-8 text, has an overlong line, more than
            :data:`MAX_ROWS` rows, or a malformed line (the first one, named by file and line,
            as the format's reference parser says).

    """
    _settle_allocator()
    values: list[list[FloatArray]] = [[] for _ in fmt.kinds]
    lines: list[list[IntArray]] = [[] for _ in fmt.kinds]
    seen = False  # a line holding data came before
    line = 1  # the number of the block's first line
    rows = 0
    try:
        for data in _blocks(path, fmt.expected):
            block = Block(data, fmt.commas)
            got, seen = _read_block(block, fmt, path, line, seen)
            line += block.lines
            rows += sum(n.size for _, n in got)
            if rows > MAX_ROWS:
                last = np.sort(np.concatenate([n for _, n in got]))[MAX_ROWS - rows]
                raise LogFormatError(
                    f"{path}:{last}: more than {MAX_ROWS:,} measurement lines, the most a log "
                    "may have (about 1.6 GB of arrays); split the log or leave out what the map "
                    "does not use (loop candidates below the score threshold)"
                )
            for k, (v, n) in enumerate(got):
                if n.size:
                    values[k].append(v)
                    lines[k].append(n)
    except _LineTooLong:
        raise LogFormatError(
            f"{path}:{line}: a line longer than {MAX_LINE >> 20} MiB; expected {fmt.expected}"
        ) from None
    out = []
    for k, kind in enumerate(fmt.kinds):
        width = len(kind.columns)
        out.append(
            Rows(
                kind.what,
                kind.columns,
                path,
                np.concatenate(values[k]) if values[k] else np.zeros((0, width)),
                np.concatenate(lines[k]) if lines[k] else np.zeros(0, np.int64),
            )
        )
    return out


_allocator_settled = False


def _settle_allocator() -> None:
    """Let the C allocator keep a block's work space for the next block (once per process).

    glibc's malloc hands blocks above a threshold (128 KiB at first) to the kernel and gives
    them back when freed; the threshold rises to the size of such a freed block, up to 32 MiB,
    and memory is returned from the heap's top only beyond twice the threshold. A block's work
    arrays (about 30 MB of 1 MiB ones) were therefore mapped and page-faulted afresh block after
    block: reading 10 M loop lines took 9.9 s with 4.5 s in the kernel (1.7 M page faults),
    6.9 s after one 30 MiB array was made and freed first (0.1 M faults). That is what this
    does; other allocators ignore it.
    """
    global _allocator_settled
    if not _allocator_settled:
        np.empty(30 << 20, np.uint8)  # made and freed at once
        _allocator_settled = True


class _LineTooLong(Exception):
    """A line longer than :data:`MAX_LINE` (:func:`read_rows` names it)."""


def _blocks(path: Path, expected: str) -> Iterator[bytes]:
    """The bytes of ``path`` in blocks of whole lines, about :data:`BLOCK` at a time.

    Raises:
        InputFileError: a missing or unreadable file.
        LogFormatError: not UTF-8 text.
        _LineTooLong: a line longer than :data:`MAX_LINE`.

    """
    if not path.is_file():
        raise InputFileError(f"{path}: no such file")
    try:
        handle = path.open("rb")
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read it ({exc.strerror})") from None
    with handle:
        carry = b""
        start = True
        while True:
            try:
                data = handle.read(BLOCK)
            except OSError as exc:
                raise InputFileError(f"{path}: cannot read it ({exc.strerror})") from None
            if start:
                data = data.removeprefix(BOM)
                start = False
            buf = carry + data if carry else data
            if not data:
                if buf:
                    _check_text(path, buf, expected)
                    yield buf
                return
            cut = _last_line_end(buf)
            if cut < 0:
                if len(buf) > MAX_LINE:
                    _check_text(path, buf, expected)
                    raise _LineTooLong
                carry = buf
                continue
            whole, carry = buf[: cut + 1], buf[cut + 1 :]
            _check_text(path, whole, expected)
            yield whole


def _last_line_end(buf: bytes) -> int:
    r"""Position of the last certain line end in ``buf`` (a final ``\r`` may be half a CRLF)."""
    cut = buf.rfind(b"\n")
    cr = buf.rfind(b"\r", 0, len(buf) - 1)
    return max(cut, cr)


def _check_text(path: Path, data: bytes, expected: str) -> None:
    if not data.isascii():
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            raise LogFormatError(f"{path}: not a text file; expected {expected}") from None


def _read_block(
    block: Block, fmt: LineFormat, path: Path, first_line: int, seen: bool
) -> tuple[list[tuple[FloatArray, IntArray]], bool]:
    """Per kind, the kept numbers and line numbers of the block's lines; whether data was seen.

    ``seen``: a line before the block held data.
    """
    kind, offset = fmt.classify(block)
    width = block.counts - offset
    fits = np.zeros(block.lines, bool)
    for k, spec in enumerate(fmt.kinds):
        for w in spec.widths:
            fits |= (kind == k) & (width == w)
    block.odd |= (kind >= 0) & ~fits
    kind = np.where(block.odd, -1, kind)
    # the numbers of the lines the array code takes: check every one, parse the kept ones
    take = np.flatnonzero(kind >= 0)
    checks: list[IntArray] = []
    parses: list[IntArray] = []
    plans: list[tuple[int, IntArray, list[int]]] = []
    for k, spec in enumerate(fmt.kinds):
        for w in spec.widths:
            rows = take[(kind[take] == k) & (width[take] == w)]
            if not rows.size:
                continue
            base = block.first[rows] + offset[rows]
            checks.append((base[:, None] + np.arange(w)).ravel())
            kept = [i for i in spec.keep if i < w]
            parse = (base[:, None] + np.asarray(kept, np.int64)).ravel()
            plans.append((k, rows, [spec.keep.index(i) for i in kept]))
            parses.append(parse)
    check = np.concatenate(checks) if checks else np.zeros(0, np.int64)
    parse = np.concatenate(parses) if parses else np.zeros(0, np.int64)
    bad, values = _numbers(block, check, parse)
    block.odd[block.line_of(check[bad])] = True
    # assemble the array code's rows, then read the odd lines with the reference parser
    out_values: list[list[FloatArray]] = [[] for _ in fmt.kinds]
    out_lines: list[list[IntArray]] = [[] for _ in fmt.kinds]
    at = 0
    for k, rows, cols in plans:
        n = rows.size * len(cols)
        v = np.full((rows.size, len(fmt.kinds[k].columns)), np.nan)
        v[:, cols] = values[at : at + n].reshape(rows.size, len(cols))
        at += n
        good = ~block.odd[rows]
        out_values[k].append(v[good])
        out_lines[k].append(rows[good])
    accepted = np.flatnonzero((kind >= 0) & ~block.odd)
    first_accepted = int(accepted[0]) if accepted.size else block.lines
    for line in np.flatnonzero(block.odd).tolist():
        first = not seen and line < first_accepted
        got, data = fmt.reference(block.text(line), f"{path}:{first_line + line}", first)
        seen = seen or data
        if got is not None:
            k, numbers = got
            out_values[k].append(np.asarray([numbers], np.float64))
            out_lines[k].append(np.asarray([line], np.int64))
    seen = seen or bool(accepted.size)
    result = []
    for k, kind_spec in enumerate(fmt.kinds):
        if not out_lines[k]:
            width_k = len(kind_spec.columns)
            result.append((np.zeros((0, width_k)), np.zeros(0, np.int64)))
            continue
        v = np.concatenate(out_values[k]) if len(out_values[k]) > 1 else out_values[k][0]
        n = np.concatenate(out_lines[k]) if len(out_lines[k]) > 1 else out_lines[k][0]
        if len(out_lines[k]) > 1:
            order = np.argsort(n, kind="stable")
            v, n = v[order], n[order]
        result.append((v, n + first_line))
    return result, seen


def _numbers(block: Block, check: IntArray, parse: IntArray) -> tuple[BoolArray, FloatArray]:
    """Which tokens of ``check`` are not plain decimal numbers, and the values of ``parse``.

    ``parse`` is a subset of ``check``; a value of a token that is not a plain number is
    meaningless (its line goes to the reference parser).
    """
    a, tstart, tend = block.a, block.tstart, block.tend
    ntok = tstart.size
    checked = np.zeros(ntok, bool)
    checked[check] = True
    # a copy of the bytes holding only the checked tokens, then their bytes that are not digits
    buf = a.copy()
    block.blank(buf, np.flatnonzero(~checked))
    if block.commas is not None:
        buf[block.commas] = 32
    buf[block.strange] = 32
    other = np.flatnonzero(((buf - 48) >= 10) & (buf > 32))
    tok = np.searchsorted(tstart, other, side="right") - 1
    ch = buf[other]
    dot = ch == 46
    exp = (ch | 32) == 101
    sign = (ch == 45) | (ch == 43)
    bad = np.zeros(ntok, bool)
    bad[tok[~(dot | exp | sign)]] = True
    dot_tok = tok[dot]  # (sorted: a token with two dots appears twice in a row)
    bad[dot_tok[1:][dot_tok[1:] == dot_tok[:-1]]] = True
    has_dot = np.zeros(ntok, bool)
    has_dot[dot_tok] = True
    dot_at = np.zeros(ntok, np.int64)
    dot_at[dot_tok] = other[dot]
    # signs: first in the token, or right after its e
    at_sign, sign_tok = other[sign], tok[sign]
    after_e = ((buf[np.maximum(at_sign - 1, 0)] | 32) == 101) & (at_sign > tstart[sign_tok])
    bad[sign_tok[(at_sign != tstart[sign_tok]) & ~after_e]] = True
    lead = (at_sign == tstart[sign_tok]).astype(np.int64)
    lead_sign = np.zeros(ntok, np.int64)
    lead_sign[sign_tok] = lead  # (a token with two leading signs is bad already)
    negative = np.zeros(ntok, bool)
    negative[sign_tok[lead == 1]] = buf[at_sign[lead == 1]] == 45
    mantissa_end = tend.copy()
    exp_digits = np.ones(ntok, np.int64)
    exp_tok = tok[exp]
    with_exp = np.unique(exp_tok)
    if with_exp.size:
        bad[exp_tok[1:][exp_tok[1:] == exp_tok[:-1]]] = True
        exp_at = np.zeros(ntok, np.int64)
        exp_at[exp_tok] = other[exp]
        at = exp_at[with_exp]
        mantissa_end[with_exp] = at
        bad[with_exp] |= has_dot[with_exp] & (dot_at[with_exp] > at)
        follows = buf[np.minimum(at + 1, buf.size - 1)]
        exp_sign = ((follows == 45) | (follows == 43)) & (at + 1 < tend[with_exp])
        exp_digits[with_exp] = tend[with_exp] - at - 1 - exp_sign
    digits = mantissa_end - tstart - lead_sign - has_dot
    bad |= (digits < 1) | (exp_digits < 1)
    # parse: plain numbers of at most 18 + 4 digits by the integer reader, the others by float
    parsed = np.zeros(ntok, bool)
    parsed[parse] = True
    parsed &= ~bad
    hard = parsed & ((digits > _MAX_DIGITS) | (exp_digits > _MAX_EXPONENT_DIGITS))
    parsed &= ~hard
    ints = np.flatnonzero(parsed)  # in file order, as the integer reader meets them
    value = np.zeros(ntok)
    hard_tokens = np.flatnonzero(hard)
    if ints.size:
        block.blank(buf, np.flatnonzero(checked & ~parsed))
        e = parsed[with_exp] if with_exp.size else np.zeros(0, bool)
        if e.any():
            buf[mantissa_end[with_exp[e]]] = 32  # the e: mantissa and exponent are two integers
        dotted = ints[has_dot[ints]]
        _drop_dots(buf, a, tstart[dotted], dot_at[dotted])
        numbers = _integers(buf, ints.size + int(np.count_nonzero(e)))
        if e.any():
            has_e = np.zeros(ntok, np.int64)
            has_e[with_exp[e]] = 1
            shift = has_e[ints]
            at = np.arange(ints.size) + np.cumsum(shift) - shift
            m = numbers[at]
            x = np.where(shift == 1, numbers[np.minimum(at + 1, numbers.size - 1)], 0)
        else:
            m = numbers
            x = 0
        frac = np.where(has_dot[ints], mantissa_end[ints] - dot_at[ints] - 1, 0)
        power = x - frac
        np.abs(m, out=m)
        exact = (m <= _EXACT_MANTISSA) & (np.abs(power) <= _EXACT_POWER)
        scale = _POW10[np.minimum(np.abs(power), _EXACT_POWER)]
        v = m.astype(np.float64)  # exact where it counts: m <= 2**53
        up = power > 0
        np.multiply(v, scale, out=v, where=up)
        np.divide(v, scale, out=v, where=~up)
        np.negative(v, out=v, where=negative[ints])
        value[ints] = v
        hard_tokens = np.concatenate([hard_tokens, ints[~exact]])
    for t in hard_tokens.tolist():
        value[t] = float(bytes(a[tstart[t] : tend[t]]))
    return bad[check], value[parse]


def _drop_dots(
    buf: NDArray[np.uint8], a: NDArray[np.uint8], start: IntArray, dot: IntArray
) -> None:
    """Take the dots out of numbers in ``buf``: what comes before a dot moves one byte right.

    ``a`` holds the original bytes; ``start`` and ``dot`` are each number's first byte and dot.
    """
    if not start.size:
        return
    length = dot - start
    offset = np.cumsum(length) - length
    total = int(offset[-1] + length[-1])
    if total:
        index = np.repeat(start - offset, length) + np.arange(total)
        buf[index + 1] = a[index]
    buf[start] = 32


def _integers(buf: NDArray[np.uint8], expected: int) -> IntArray:
    """The ``expected`` integers written in ``buf`` (blank separated, signs allowed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        numbers = np.fromstring(buf.tobytes(), dtype=np.int64, sep=" ")
    if numbers.size != expected:  # pragma: no cover - the grammar check rules this out
        raise AssertionError(f"integer reader found {numbers.size} numbers, not {expected}")
    return numbers
