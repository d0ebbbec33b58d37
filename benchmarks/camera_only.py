"""Camera-only mapping: the default layout rendered without odometry, mapped with RatSLAM's
visual odometry (issue 26 part 2).

    python benchmarks/camera_only.py [--layout NAME] [--video] [--keep DIR]

The run is generated once (``cogmap make-maze --camera-only``: a folder of JPEG images, with
``--video`` also an ``.mp4``) into ``--keep`` (default ``$COGMAP_CACHE/camera``), then mapped in
this process as ``cogmap run`` maps it: the images decoded, visual odometry, the front end and
the three maps, timed end to end. Printed per map: its ATE, the ATE of the visual dead reckoning
(the same odometry without the map: the reference, from the same run), their ratio, and the
completeness and correctness of the layout at 0.25 m; then the run's speed against real time.

Targets: every map >= 3 x better than the visual dead reckoning, completeness and correctness
>= 0.9 at 0.25 m, >= 50 x real time. Exit status 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cogmap_core.datasets.cache import DATASET_VERSION, cache_dir  # noqa: E402
from cogmap_core.datasets.camera_writer import generate_camera_only  # noqa: E402
from cogmap_core.datasets.generator import MazeConfig  # noqa: E402
from cogmap_core.datasets.layout import DEFAULT_LAYOUT  # noqa: E402
from cogmap_core.datasets.profile import frontend_config_for  # noqa: E402
from cogmap_core.evaluation import map_accuracy  # noqa: E402
from cogmap_core.map_modes import ALL_MODES  # noqa: E402
from cogmap_core.slam import SlamSession  # noqa: E402
from cogmap_core.sources.detect import KINDS, CameraOptions, open_source  # noqa: E402

RADIUS = 0.25
TARGET_RATIO = 3.0
TARGET_FIDELITY = 0.9
TARGET_SPEED = 50.0


def dataset(folder: Path, layout: str, suffix: str) -> Path:
    """The camera-only run of ``layout`` (6 laps, seed 1), generated on first use."""
    path = folder / f"{Path(layout).stem}_6laps_seed1_v{DATASET_VERSION}_camera{suffix}"
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        print(f"generating {path} (first use only)", flush=True)
        generate_camera_only(path, MazeConfig(layout=layout), overwrite=True)
    return path


def run(path: Path) -> bool:
    """Map ``path`` camera-only; print the figures; return whether every target is met."""
    frontend = frontend_config_for(path)
    started = time.perf_counter()
    cpu_started = time.process_time()
    kind = KINDS["video" if path.suffix else "images"]  # as cogmap run maps it
    session = SlamSession(kind.map_params, frontend_config=frontend)
    with open_source(path, camera=CameraOptions(frontend=frontend)) as reader:
        for frame in reader.frames():
            session.process(frame)
    session.finish()
    wall = time.perf_counter() - started
    cpu = time.process_time() - cpu_started
    log = session.log
    duration = float(log.frame_time[-1] - log.frame_time[0])
    dead = log.dead_reckoning_ate()
    if dead is None:
        print(f"{path}: no ground truth; nothing to measure")
        return False
    truth_path = np.asarray(log.ground_truth)
    print(f"{path.name}: {log.frames} frames, {duration:.1f} s of data")
    print(f"  visual dead reckoning ATE {dead:.3f} m (the reference)")
    ok = True
    for mode in ALL_MODES:
        snapshot = session.maps[mode].snapshot()
        truth = log.truth_at(snapshot.vertex_time)
        assert truth is not None
        accuracy = map_accuracy(snapshot, truth, truth_path, RADIUS)
        ate = accuracy.ate if accuracy.ate is not None else float("inf")
        ratio = dead / ate
        fid = accuracy.fidelity
        met = (
            ratio >= TARGET_RATIO
            and fid.completeness >= TARGET_FIDELITY
            and fid.correctness >= TARGET_FIDELITY
        )
        ok &= met
        print(
            f"  {mode.value:<18} {snapshot.poses.shape[0]:5d} vertices  ATE {ate:.3f} m  "
            f"{ratio:4.1f} x better than dead reckoning  completeness {fid.completeness:.3f}  "
            f"correctness {fid.correctness:.3f} at {RADIUS} m  {'ok' if met else 'MISSED'}"
        )
    speed = duration / wall
    ok &= speed >= TARGET_SPEED
    print(
        f"  {wall:.1f} s for {duration:.1f} s of data (decoding, visual odometry, front end, "
        f"three maps): {speed:.1f} x real time  {'ok' if speed >= TARGET_SPEED else 'MISSED'}; "
        f"CPU time {cpu:.1f} s: {duration / cpu:.1f} x (load average {os.getloadavg()[0]:.1f} "
        f"on {os.cpu_count()} cores)"
    )
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--layout", default=DEFAULT_LAYOUT, help="built-in layout or file")
    parser.add_argument("--video", action="store_true", help="also map it as an .mp4 video")
    parser.add_argument("--keep", type=Path, default=None, help="folder for the datasets")
    args = parser.parse_args()
    folder = args.keep or cache_dir() / "camera"
    inputs = [dataset(folder, args.layout, "")]
    if args.video:
        inputs.append(dataset(folder, args.layout, ".mp4"))
    ok = all([run(path) for path in inputs])
    print(f"targets: {'all met' if ok else 'NOT all met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
