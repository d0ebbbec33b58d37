"""The array parser of log text reads exactly what the reference parser reads, bit for bit.

Files of random lines -- plain numbers, every spelling Python's ``float`` takes or refuses,
comments, headers, malformed lines, CRLF and CR line ends, blocks cut anywhere -- are read by
:func:`~cogmap_core.sources.log_text.read_rows` and by the format's reference parser alone: the
same rows and line numbers, or the same first error.
"""

from __future__ import annotations

import math
import random
import re
from pathlib import Path

import numpy as np
import pytest

from cogmap_core.sources import log_text
from cogmap_core.sources.log_text import BOM, LineFormat, LogFormatError, Rows, read_rows
from cogmap_core.sources.odometry_csv import LOOP_FORMAT, ODOMETRY_FORMAT
from cogmap_core.sources.odometry_csv import TRUTH_FORMAT as CSV_TRUTH_FORMAT
from cogmap_core.sources.tuc import INPUT_FORMAT, TRUTH_FORMAT, read_tuc


class Reference(LineFormat):
    """A format read line by line by its reference parser only (the specification)."""

    def __init__(self, fmt: LineFormat) -> None:
        self.fmt = fmt
        self.kinds = fmt.kinds
        self.expected = fmt.expected
        self.commas = fmt.commas

    def classify(self, block):  # noqa: ANN001, ANN201
        block.odd[:] = True
        return np.full(block.lines, -1), np.zeros(block.lines, np.int64)

    def reference(self, text: str, where: str, first: bool):  # noqa: ANN201
        return self.fmt.reference(text, where, first)


NUMBERS = [
    "0", "-0", "+0", "7", "-12", "0.5", "-0.0025", "1380.0891177654", ".5", "5.", "-.5",
    "+.5e-3", "1e5", "1E+05", "4.9411787640057e-05", "-2.1050699229461e-05", "00012.500",
    "123456789012345678", "1234567890123456789", "9007199254740993", "0.30000000000000004",
    "1.000000000000000000e+00", "1e22", "1e23", "1e-22", "1.5e-300", "1e400", "2.5e0000",
    "nan", "inf", "-Infinity", "1_000", "\u0663", "1.2.3", "1-2", "--1", "e5", "1e", "+", ".",
    "1e5.0", "0x10", "1,5", "12a", "1e+", "١٢.٥",
]  # fmt: skip
BLANKS = [" ", "  ", "\t", " \t", "\x0c", "\u00a0"]


def fuzz_line(rng: random.Random, kind: str, count: int, commas: bool) -> str:
    words = [
        rng.choice(NUMBERS)
        if rng.random() < 0.3
        else f"{rng.uniform(-1e3, 1e3):.{rng.randint(0, 16)}f}"
        for _ in range(count)
    ]
    if commas:
        fields = [rng.choice(["", " ", "\t"]) + w + rng.choice(["", " "]) for w in words]
        return ",".join(fields)
    parts = ([kind] if kind else []) + words
    line = rng.choice(BLANKS[:5]).join(parts)
    return rng.choice(["", " ", "\t"]) + line + rng.choice(["", " ", " \t "])


def fuzz_file(rng: random.Random, kinds: list[tuple[str, int]], commas: bool, n: int) -> bytes:
    lines = []
    for _ in range(n):
        r = rng.random()
        if r < 0.05:
            lines.append(rng.choice(["", "   ", "# comment, with, commas", "#", "\t# x"]))
        elif r < 0.08 and commas:
            lines.append(rng.choice(["time,v,omega", ",1,2", "1,2,", "1,,2", "1 2,3,4", ",,"]))
        elif r < 0.08:
            lines.append(rng.choice(["odm2 1 2 3", "loop 1 2", "point2", "loop\u00a01 2 3"]))
        else:
            kind, count = rng.choice(kinds)
            count += 1 if rng.random() < 0.02 else 0
            lines.append(fuzz_line(rng, kind, count, commas))
    ends = [rng.choice(["\n", "\r\n", "\r"]) if rng.random() < 0.1 else "\n" for _ in lines]
    text = "".join(line + end for line, end in zip(lines, ends, strict=True))
    return (BOM if rng.random() < 0.3 else b"") + text.encode()


def same_result(path: Path, fmt: LineFormat) -> None:
    """read_rows with the array parser gives the reference's rows, bit for bit, or its error."""

    def outcome(f: LineFormat) -> list[Rows] | str:
        try:
            return read_rows(path, f)
        except LogFormatError as exc:
            return str(exc)

    got, expected = outcome(fmt), outcome(Reference(fmt))
    if isinstance(expected, str):
        assert got == expected
        return
    assert not isinstance(got, str), got
    for mine, theirs in zip(got, expected, strict=True):
        assert mine.lines.tolist() == theirs.lines.tolist()
        assert mine.values.shape == theirs.values.shape
        assert mine.values.view(np.int64).tolist() == theirs.values.view(np.int64).tolist()


@pytest.mark.parametrize("seed", range(40))
@pytest.mark.parametrize("block", [64, 4096])
def test_the_array_parser_reads_what_the_reference_reads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int, block: int
) -> None:
    monkeypatch.setattr(log_text, "BLOCK", block)  # lines and CRLFs across block ends
    rng = random.Random(seed)
    clean = seed % 2 == 0  # half the files have only good lines: no error ends the comparison
    formats: list[tuple[LineFormat, list[tuple[str, int]], bool]] = [
        (INPUT_FORMAT, [("odom2", 7), ("loop", 3)], False),
        (TRUTH_FORMAT, [("point2", 7), ("angle", 3)], False),
        (ODOMETRY_FORMAT, [("", 3)], True),
        (LOOP_FORMAT, [("", 3)], True),
        (CSV_TRUTH_FORMAT, [("", 3), ("", 4)], True),
    ]
    for k, (fmt, kinds, commas) in enumerate(formats):
        data = fuzz_file(rng, kinds, commas, 60)
        if clean:
            text = data.decode().replace("\r\n", "\n").replace("\r", "\n")
            good = [line for line in text.split("\n") if _valid(line, fmt)]
            data = "\n".join(good).encode()
        path = tmp_path / f"f{k}.txt"
        path.write_bytes(data)
        same_result(path, fmt)


def _valid(line: str, fmt: LineFormat) -> bool:
    try:
        Reference(fmt).reference(line, "x:1", False)
    except LogFormatError:
        return False
    return True


def test_numbers_are_read_exactly_as_python_reads_them(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    values = np.concatenate(
        [
            rng.uniform(-1e4, 1e4, 3000),
            rng.standard_normal(3000) * 10.0 ** rng.integers(-30, 30, 3000),
            [round(float(v), k % 12) for k, v in enumerate(rng.uniform(0, 2000, 3000))],
        ]
    )
    words = [repr(float(v)) for v in values] + [f"{v:.14g}" for v in values]
    words += [f"{v:.{k % 19}f}" for k, v in enumerate(values)]
    words += [f"{v:.{k % 20}e}" for k, v in enumerate(values)]
    path = tmp_path / "n_Input.txt"
    lines = [f"loop {words[k]} {words[k + 1]} {words[k + 2]}" for k in range(0, len(words) - 2, 3)]
    path.write_text("\n".join(lines) + "\n")
    _, loops = read_rows(path, INPUT_FORMAT)
    expected = [[float(w) for w in line.split()[1:]] for line in lines]
    assert loops.values.view(np.int64).tolist() == np.array(expected).view(np.int64).tolist()
    assert not any(math.isnan(v) for v in loops.values.ravel())


def test_lines_are_numbered_across_every_kind_of_line_end(tmp_path: Path) -> None:
    path = tmp_path / "ends_Input.txt"
    path.write_bytes(b"odom2 0 1 0 0 0 0 0\rodom2 1 1 0 0 0 0 0\r\n\nodom2 2 x 0 0 0 0 0\n")
    with pytest.raises(LogFormatError, match=re.escape(f"{path}:4: 'x' in a 'odom2' line")):
        read_tuc(path)


def test_a_file_of_more_rows_than_the_cap_is_refused_at_that_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(log_text, "MAX_ROWS", 10)
    monkeypatch.setattr(log_text, "BLOCK", 64)  # the cap is crossed inside a block
    path = tmp_path / "big_Input.txt"
    lines = ["# twelve rows"] + [f"odom2 {k} 0.5 0 0 0 0 0" for k in range(6)]
    lines += [f"loop {k + 3} 1 0.5" for k in range(6)]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError) as caught:
        read_tuc(path)
    assert str(caught.value) == (
        f"{path}:12: more than 10 measurement lines, the most a log may have (about 1.6 GB of "
        "arrays); split the log or leave out what the map does not use (loop candidates below "
        "the score threshold)"
    )
    monkeypatch.setattr(log_text, "MAX_ROWS", 12)
    assert read_tuc(path).loops.shape == (6, 3)
