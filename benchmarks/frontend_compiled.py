"""The front end's compiled loops against its numpy code: same outputs, time per frame (issue 26).

Usage::

    python benchmarks/frontend_compiled.py [--bag BAG] [--settings irat|profile] [--frames N]
        [--repeats 3]

The bag's frames (default: the default dataset) are decoded once into memory, then
:class:`~cogmap_core.frontend.FrontEnd` runs over them with its numpy code
(``COGMAP_COMPILED_FRONTEND=0``) and with its compiled loops, alternately, ``--repeats`` times.
Every frame's template, offset, error, events and pose-cell peak must be equal between the two
(the script fails otherwise). Printed: CPU milliseconds per frame of ``FrontEnd.process`` (thread
time: a shared machine disturbs wall time less), the best of the repeats, and the ratio.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cogmap_core.datasets.cache import default_dataset_path  # noqa: E402
from cogmap_core.datasets.profile import GENERATED_FRONTEND_PROFILE  # noqa: E402
from cogmap_core.datasets.rosbag_reader import open_bag  # noqa: E402
from cogmap_core.frames import Frame  # noqa: E402
from cogmap_core.frontend import FrontEnd, FrontEndConfig  # noqa: E402
from cogmap_core.frontend.compiled import ENV_SWITCH, kernels  # noqa: E402


def run(frames: list[Frame], config: FrontEndConfig, compiled: bool) -> tuple[float, list[Any]]:
    """CPU seconds per frame and every frame's outputs, with or without the compiled loops."""
    os.environ[ENV_SWITCH] = "1" if compiled else "0"
    try:
        warm = FrontEnd(config)  # compile (or load) outside the timing
        for frame in frames[:20]:
            warm.process(frame)
        frontend = FrontEnd(config)
    finally:
        os.environ.pop(ENV_SWITCH, None)
    assert (frontend.local_view._compiled is not None) == compiled
    outputs: list[Any] = []
    cpu = 0.0
    for frame in frames:
        start = time.thread_time()
        events = frontend.process(frame)
        cpu += time.thread_time() - start
        view = frontend.last_view
        assert view is not None
        outputs.append((view.template_id, view.offset, view.error, repr(events)))
        outputs.append(frontend.pose_cell_peak)
    return cpu / len(frames), outputs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bag", type=Path, default=None, help="default: the default dataset")
    parser.add_argument("--settings", choices=("irat", "profile"), default="irat")
    parser.add_argument("--frames", type=int, default=None, help="first N frames only")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if kernels() is None:
        print("numba is not available (or COGMAP_COMPILED_FRONTEND=0): nothing to compare")
        return 1
    bag = args.bag or default_dataset_path()
    with open_bag(bag, image_scale=1) as reader:
        frames = []
        for frame in reader.frames():
            if args.frames is not None and frame.index >= args.frames:
                break
            frames.append(frame)
    changes = {} if args.settings == "irat" else dict(GENERATED_FRONTEND_PROFILE)
    config = FrontEndConfig().with_changes(**changes)
    best = {False: float("inf"), True: float("inf")}
    reference = None
    for _ in range(args.repeats):
        for compiled in (False, True):
            seconds, outputs = run(frames, config, compiled)
            best[compiled] = min(best[compiled], seconds)
            if reference is None:
                reference = outputs
            elif outputs != reference:
                print("the compiled loops' outputs differ from the numpy code's", file=sys.stderr)
                return 1
    print(f"{bag.name}, {args.settings} settings, {len(frames)} frames: identical outputs")
    print(
        f"FrontEnd.process: numpy {best[False] * 1e3:.3f} ms/frame, compiled "
        f"{best[True] * 1e3:.3f} ms/frame (CPU, best of {args.repeats}): "
        f"{best[False] / best[True]:.2f} x"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
