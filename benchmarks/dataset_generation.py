"""Benchmark: generating a 15-minute synthetic dataset (budget: 2 minutes on 2 cores), and the
bag reader's per-frame cost at full and reduced JPEG decoding.

    python benchmarks/dataset_generation.py [--minutes 15] [--workers N] [--out FILE.bag]

The layout is the default iRat-like maze; the number of laps is the smallest that gives at least
``--minutes`` of data. Prints the generation time, its ratio to the 120 s budget (scaled to
exactly 15 minutes of data), and the reader's milliseconds per frame for image scales 1, 2, 4, 8.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from cogmap_core.datasets import MazeConfig, generate_maze_bag, open_bag
from cogmap_core.datasets.generator import plan_dataset

BUDGET_S = 120.0
BUDGET_DATA_S = 15 * 60.0


def laps_for(minutes: float, seed: int) -> tuple[int, float]:
    """Smallest lap count giving at least ``minutes`` of data, and that duration (s)."""
    laps = 1
    while True:
        duration = plan_dataset(MazeConfig(laps=laps, seed=seed)).trajectory.duration
        if duration >= minutes * 60.0:
            return laps, duration
        laps += 1


def read_cost(path: Path, scale: int) -> tuple[int, float]:
    """Frames read and seconds spent reading the whole bag at an image scale."""
    with open_bag(path, image_scale=scale) as reader:
        start = time.perf_counter()
        n = sum(1 for _ in reader.frames())
        return n, time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=15.0, help="data duration (min)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=None, help="default: all CPUs")
    parser.add_argument("--out", type=Path, default=None, help="keep the bag here")
    parser.add_argument("--skip-read", action="store_true", help="do not time the reader")
    args = parser.parse_args()

    laps, planned = laps_for(args.minutes, args.seed)
    print(f"cpus: {os.cpu_count()}, layout irat_australia, {laps} laps = {planned / 60:.1f} min")
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "bench.bag"
        result = generate_maze_bag(
            out, MazeConfig(laps=laps, seed=args.seed), overwrite=True, workers=args.workers
        )
        per_15 = result.elapsed * BUDGET_DATA_S / result.duration
        print(
            f"generated {result.frames} frames ({result.duration / 60:.1f} min of data, "
            f"{result.size_bytes / 1e6:.0f} MB) in {result.elapsed:.1f} s with "
            f"{result.workers} process(es): {1e3 * result.elapsed / result.frames:.2f} ms/frame"
        )
        print(
            f"15-minute dataset: {per_15:.1f} s, {per_15 / BUDGET_S:.2f} of the "
            f"{BUDGET_S:.0f} s budget ({'OK' if per_15 <= BUDGET_S else 'OVER BUDGET'})"
        )
        if not args.skip_read:
            for scale in (1, 2, 4, 8):
                n, seconds = read_cost(out, scale)
                print(
                    f"read at scale 1/{scale}: {1e3 * seconds / n:.3f} ms/frame "
                    f"({result.duration / seconds:.0f}x real time, one core)"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
