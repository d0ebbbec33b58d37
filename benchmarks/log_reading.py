"""Reading odometry + place-recognition logs: speed and peak memory of the TUC reader.

Generates TUC input files in a temporary folder (never in the repository), reads each in a fresh
child process (``read_tuc``, no ground truth) and prints the read's wall and CPU time (the machine
may be shared: CPU time is the steadier figure), lines per second and the child's peak resident
memory. Cases:

- ``loops N``: N lines, 99 % ``loop`` lines (a hostile probe's shape: a place recognition that
  reports every candidate it compared), 1 % ``odom2`` lines at 10 Hz spanning their times;
- ``lecture-hall N``: the real Lecture Hall input repeated end to end (times shifted) to N lines,
  its formatting kept (trailing blanks, 73 % ``odom2`` lines);
- ``Lecture Hall``: the real file as it is (best of 5 reads in one process), with a SHA-256 of
  the parsed arrays and of the steps ``LogReader`` makes, to compare readers bit for bit.

Targets (issue "log loader"): a 10 M-line log reads in <= 10 s with < 2 GB peak RSS.

Usage: ``python benchmarks/log_reading.py [--sizes 1000000,10000000] [--data DIR] [--keep DIR]``
(``--keep``: keep the generated files there and read them again next time, not in the repository)
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = """
import resource, sys, time
from cogmap_core.sources.tuc import read_tuc
t, cpu = time.perf_counter(), time.process_time()
log = read_tuc(sys.argv[1], use_ground_truth=False)
dt, cpu = time.perf_counter() - t, time.process_time() - cpu
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
dropped = sum(getattr(log, "read_counts", {}).get(k, 0) for k in ("loops_same_view",))
print(dt, cpu, rss, log.odometry.shape[0], log.loops.shape[0] + dropped)
"""


def data_dir(given: Path | None) -> Path:
    """Where the TUC files are (``--data``, ``$COGMAP_TUC_DIR`` or ``../shared/real/tuc``)."""
    if given is not None:
        return given
    env = os.environ.get("COGMAP_TUC_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared/real/tuc"


def write_loops(path: Path, n: int) -> None:
    """``n`` lines: an ``odom2`` line every 0.1 s (and last), 99 ``loop`` lines between two."""
    rng = np.random.default_rng(1)
    per = 100
    with path.open("w") as out:
        for block in range(0, n, 50_000):
            k = np.arange(block, min(n, block + 50_000))
            t = 0.1 * (k // per)
            odom = (k % per == 0) | (k == n - 1)
            t[k == n - 1] += 0.099  # the last line is odometry: every loop lies within it
            lines = []
            matched = rng.uniform(0, np.maximum(t - 5.0, 0.0))
            score = rng.uniform(0.0, 1.0, k.size)
            for i in range(k.size):
                if odom[i]:
                    lines.append(f"odom2 {t[i]:.4f} 0.5 0 0.01 0.0025 0.0025 0.0001\n")
                else:
                    stamp = t[i] + 0.001 * (k[i] % per)
                    lines.append(f"loop {stamp:.4f} {matched[i]:.10f} {score[i]:.14f}\n")
            out.writelines(lines)


def shifted(line: str, shift: float) -> str:
    """A Lecture Hall line with its times moved ``shift`` seconds on (10 decimals, as written)."""
    words = line.split(" ")
    count = 2 if words[0] == "loop" else 1  # a loop's matched time moves too
    for i in range(1, 1 + count):
        words[i] = f"{float(words[i]) + shift:.10f}"
    return " ".join(words)


def write_lecture_hall(path: Path, source: Path, n: int) -> None:
    """The real input file repeated to ``n`` lines, each copy's times after the previous."""
    lines = source.read_text().splitlines(keepends=True)
    span = max(float(line.split()[1]) for line in lines) + 1.0
    written = 0
    copy = 0
    with path.open("w") as out:
        while written < n:
            chunk = lines[: n - written]
            if copy:
                chunk = [shifted(line, copy * span) for line in chunk]
            out.writelines(chunk)
            written += len(chunk)
            copy += 1


def read_in_child(path: Path) -> tuple[float, float, float, int, int]:
    """Wall and CPU seconds, peak RSS (MB), odometry samples and loop lines of reading ``path``
    in a new process."""
    result = subprocess.run(
        [sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=False
    )
    if result.returncode != 0:
        raise SystemExit(f"reading {path} failed:\n{result.stderr}")
    dt, cpu, rss, odo, loops = result.stdout.split()
    return float(dt), float(cpu), float(rss), int(odo), int(loops)


def lecture_hall(source: Path) -> None:
    """Best-of-5 read time of the real file and hashes of what it becomes."""
    from cogmap_core.sources.log_reader import LogReader
    from cogmap_core.sources.tuc import read_tuc

    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        log = read_tuc(source)
        best = min(best, time.perf_counter() - t)
    arrays = hashlib.sha256()
    for a in (log.odometry, log.loops, log.ground_truth):
        assert a is not None
        arrays.update(repr((a.shape, a.dtype.str)).encode())
        arrays.update(np.ascontiguousarray(a).tobytes())
    steps = hashlib.sha256(repr(LogReader(log).steps).encode()).hexdigest()
    print(f"Lecture Hall (with ground truth): read in {best * 1e3:.1f} ms (best of 5)")
    print(f"  arrays sha256 {arrays.hexdigest()}")
    print(f"  steps  sha256 {steps}")


def main() -> None:
    """Generate, read and print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000000,10000000")
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument(
        "--keep", type=Path, default=None, help="keep the files here (and reuse them)"
    )
    args = parser.parse_args()
    source = data_dir(args.data) / "Lecture_Hall_Input.txt"
    sizes = [int(s) for s in args.sizes.split(",") if s]
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(
            f"{'case':14} {'lines':>10} {'MB':>6} {'read s':>7} {'CPU s':>6} {'lines/s':>10} "
            f"{'peak MB':>8}"
        )
        for n in sizes:
            cases = [("loops", write_loops)]
            if source.is_file():
                cases.append(("lecture-hall", lambda p, k: write_lecture_hall(p, source, k)))
            for name, write in cases:
                path = folder / f"{name}-{n}_Input.txt"
                if not (args.keep and path.is_file()):
                    write(path, n)
                size = path.stat().st_size / 1e6
                dt, cpu, rss, odo, loops = read_in_child(path)
                assert odo + loops == n, (odo, loops, n)
                print(
                    f"{name:14} {n:10d} {size:6.0f} {dt:7.2f} {cpu:6.2f} {n / dt:10.0f} {rss:8.0f}"
                )
                if not args.keep:
                    path.unlink()
    if source.is_file():
        lecture_hall(source)
    else:
        print(f"no {source}: Lecture Hall skipped")


if __name__ == "__main__":
    main()
