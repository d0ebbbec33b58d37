"""cogmap's front end against OpenRatSLAM's on the same bag, frame by frame (issue 26).

    python benchmarks/openratslam_equivalence.py --driver PATH/TO/DRIVER [--bag BAG ...]
        [--settings irat profile] [--frames N] [--keep DIR]

OpenRatSLAM's side is a program you build from its public source (it is GPL and is never part
of this repository, nor is any recipe that builds it): a non-ROS driver that constructs its
``ratslam::LocalViewMatch``, ``PosecellNetwork`` and ``ExperienceMap`` from an ini file's
``[ratslam]`` section and feeds them the messages of a stream file in bag order, as its ROS
nodes would be fed by ``rosbag play``:

    driver CONFIG.ini STREAM.bin > RECORDS.txt

The stream (little endian) is a sequence of records, written here from the bag in the order the
bag's messages are read:

- ``b"I"``, int64 header stamp (ns), uint32 width, uint32 height, uint8 channels, then the
  decoded image (``width * height * channels`` bytes: ``mono8``, or ``bgr8`` for a colour
  JPEG, as ``image_transport`` hands it to ``main_lv``); the driver calls
  ``LocalViewMatch::on_image`` then ``PosecellNetwork::on_view_template``;
- ``b"O"``, int64 header stamp (ns), float64 ``twist.linear.x``, float64 ``twist.angular.z``;
  from the second message on, the driver calls ``PosecellNetwork::on_odo`` with the interval
  ``ros::Duration::toSec`` gives, then ``get_action``, and hands an action to the experience
  map as ``main_em`` does (create: ``on_create_experience`` + ``on_set_experience``; link:
  ``on_create_link`` + ``on_set_experience``).

Records it prints, one a line: ``F frame vt new error`` after each image; ``A frame action src
dest x y th experiences links`` for each action (``frame`` = the last image; ``x y th`` the
pose-cell peak, ``experiences`` and ``links`` the experience map's counts); at the end
``T frames odometry lv_ns pc_ns [cpu_ns]`` (wall time spent in the local view and in the pose
cells, and optionally their thread CPU time).

cogmap's side runs :class:`~cogmap_core.frontend.FrontEnd` on the frames its bag reader yields
(images decoded at full size) with the same settings, timed around ``FrontEnd.process`` alone.
Compared frame by frame: the view template id (and, since one extra template renumbers every
later one, the template named by the frame that created it), new templates, the action decided
for the frame and the pose-cell peak then, the experience and link counts (links counted as
OpenRatSLAM's experience map keeps them: one per pair of experiences), and the front ends' wall
time per frame (and CPU time, which a machine shared with other work disturbs less). Settings:
``irat`` = OpenRatSLAM's ``config_irataus`` values (cogmap's defaults), ``profile`` = the
generated bags' profile on top of them. Bags: the default dataset
and the figure-eight layout unless ``--bag`` names others (generated bags are cached in
``--keep``, default ``$COGMAP_CACHE``).
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rosbags.highlevel import AnyReader

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cogmap_core.datasets.cache import cache_dir, default_dataset_path  # noqa: E402
from cogmap_core.datasets.generator import MazeConfig, generate_maze_bag  # noqa: E402
from cogmap_core.datasets.profile import GENERATED_FRONTEND_PROFILE  # noqa: E402
from cogmap_core.datasets.rosbag_reader import open_bag  # noqa: E402
from cogmap_core.datasets.topics import BagTopics  # noqa: E402
from cogmap_core.frontend import FrontEnd, FrontEndConfig  # noqa: E402
from cogmap_core.frontend.pose_cells import ActionKind  # noqa: E402

#: OpenRatSLAM's names of the settings both front ends share (cogmap uses the same names).
SHARED_SETTINGS = (
    "image_crop_x_min",
    "image_crop_x_max",
    "image_crop_y_min",
    "image_crop_y_max",
    "template_x_size",
    "template_y_size",
    "vt_shift_match",
    "vt_step_match",
    "vt_match_threshold",
    "vt_normalisation",
    "vt_patch_normalise",
    "vt_min_patch_normalisation_std",
    "vt_active_decay",
    "pc_dim_xy",
    "pc_dim_th",
    "pc_w_e_dim",
    "pc_w_i_dim",
    "pc_w_e_var",
    "pc_w_i_var",
    "pc_global_inhib",
    "pc_vt_inject_energy",
    "pc_cell_x_size",
    "pc_vt_restore",
    "exp_delta_pc_threshold",
)

SETTINGS = {"irat": {}, "profile": dict(GENERATED_FRONTEND_PROFILE)}


@dataclass
class Run:
    """One front end's per-frame records."""

    vt: list[int] = field(default_factory=list)
    new: list[bool] = field(default_factory=list)
    action: dict[int, int] = field(default_factory=dict)  # frame -> action kind (1, 2, 3)
    peak: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    experiences: int = 0
    links: int = 0
    seconds: float = 0.0
    cpu_seconds: float = float("nan")


def write_config(path: Path, config: FrontEndConfig, image_shape: tuple[int, int]) -> None:
    """OpenRatSLAM's ini file with ``config``'s values (crop in pixels of the decoded image)."""
    height, width = image_shape
    values = {name: getattr(config, name) for name in SHARED_SETTINGS}
    sx = width / config.reference_image_width
    sy = height / config.reference_image_height
    values["image_crop_x_min"] = round(config.image_crop_x_min * sx)
    values["image_crop_x_max"] = round(config.image_crop_x_max * sx)
    values["image_crop_y_min"] = round(config.image_crop_y_min * sy)
    values["image_crop_y_max"] = round(config.image_crop_y_max * sy)
    lines = ["[general]", "topic_root=", "[ratslam]"]
    # integral values without a decimal point: OpenRatSLAM reads some of them as int
    lines += [f"{k}={int(v) if float(v).is_integer() else repr(v)}" for k, v in values.items()]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


def bag_message_stream(bag: Path, topics: BagTopics) -> Iterator[tuple[str, int, Any]]:
    """``(kind, header stamp ns, payload)`` of the camera and odometry messages in bag order."""
    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in (topics.image, topics.odometry)]
        for conn, record_ns, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            stamp = stamp or record_ns
            if conn.topic == topics.image:
                yield "image", stamp, np.asarray(msg.data, dtype=np.uint8)
            else:
                twist = msg.twist.twist
                yield "odometry", stamp, (float(twist.linear.x), float(twist.angular.z))


def write_stream(bag: Path, out: Path, limit: int | None) -> tuple[int, tuple[int, int]]:
    """The bag's camera and odometry messages, in bag order, as the driver's stream file."""
    frames = 0
    shape = (0, 0)
    tmp = out.with_name(out.name + ".tmp")
    with tmp.open("wb") as f:
        for kind, stamp_ns, payload in bag_message_stream(bag, BagTopics()):
            if kind == "image":
                if limit is not None and frames >= limit:
                    break
                image = cv2.imdecode(payload, cv2.IMREAD_UNCHANGED)
                if image is None:
                    continue
                channels = 1 if image.ndim == 2 else image.shape[2]
                shape = image.shape[:2]
                f.write(
                    b"I" + struct.pack("<qIIB", stamp_ns, image.shape[1], image.shape[0], channels)
                )
                f.write(np.ascontiguousarray(image).tobytes())
                frames += 1
            else:
                v, w = payload
                f.write(b"O" + struct.pack("<qdd", stamp_ns, v, w))
    os.replace(tmp, out)
    return frames, shape


def run_driver(driver: Path, config_file: Path, stream: Path) -> Run:
    """Run OpenRatSLAM's driver; parse its records."""
    started = time.perf_counter()
    proc = subprocess.run(
        [str(driver), str(config_file), str(stream)], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        raise SystemExit(f"driver failed ({proc.returncode}): {proc.stderr.strip()[:500]}")
    run = Run()
    for line in proc.stdout.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "F":
            run.vt.append(int(parts[2]))
            run.new.append(parts[3] == "1")
        elif parts[0] == "A":
            frame = int(parts[1])
            run.action[frame] = int(parts[2])
            run.peak[frame] = (float(parts[5]), float(parts[6]), float(parts[7]))
            run.experiences, run.links = int(parts[8]), int(parts[9])
        elif parts[0] == "T":
            run.seconds = (float(parts[3]) + float(parts[4])) / 1e9
            if len(parts) > 5:
                run.cpu_seconds = float(parts[5]) / 1e9
    if not run.seconds:
        run.seconds = time.perf_counter() - started
    return run


def run_cogmap(bag: Path, config: FrontEndConfig, limit: int | None) -> Run:
    """cogmap's front end over the bag's frames (decoded at full size), timed per frame."""
    frontend = FrontEnd(config)
    frontend.decisions = []
    run = Run()
    links: set[tuple[int, int]] = set()
    elapsed = cpu = 0.0
    with open_bag(bag, image_scale=1) as reader:
        for frame in reader.frames():
            if limit is not None and frame.index >= limit:
                break
            start, cpu_start = time.perf_counter(), time.thread_time()
            frontend.process(frame)
            elapsed += time.perf_counter() - start
            cpu += time.thread_time() - cpu_start
            view = frontend.last_view
            assert view is not None
            run.vt.append(view.template_id)
            run.new.append(view.is_new)
    for frame, action, peak, count in frontend.decisions:
        kind = {ActionKind.CREATE_NODE: 1, ActionKind.CREATE_EDGE: 2, ActionKind.SET_NODE: 3}
        run.action[frame] = kind[action.kind]
        run.peak[frame] = peak
        if action.kind is ActionKind.CREATE_NODE and count > 1:
            links.add((min(action.src, action.dest), max(action.src, action.dest)))
        elif action.kind is ActionKind.CREATE_EDGE:
            links.add((min(action.src, action.dest), max(action.src, action.dest)))
    run.experiences = frontend.vertex_count
    run.links = len(links)
    run.seconds = elapsed
    run.cpu_seconds = cpu
    return run


def by_creator(vt: list[int], new: list[bool]) -> list[int]:
    """Each frame's template named by the frame that created it."""
    creator: dict[int, int] = {}
    out = []
    for i, (t, n) in enumerate(zip(vt, new, strict=True)):
        if n:
            creator[t] = i
        out.append(creator.get(t, -1))
    return out


def peak_difference(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """Largest per-axis difference of two pose-cell peaks, in cells (theta wrapped)."""
    dx, dy, dth = (abs(p - q) for p, q in zip(a, b, strict=True))
    return max(dx, dy, min(dth, 36.0 - dth))


def compare(label: str, ors: Run, cog: Run) -> dict[str, float]:
    """Print and return the frame-by-frame agreement of the two runs."""
    n = min(len(ors.vt), len(cog.vt))
    same_vt = sum(a == b for a, b in zip(ors.vt[:n], cog.vt[:n], strict=True)) / n
    named_o = by_creator(ors.vt[:n], ors.new[:n])
    named_c = by_creator(cog.vt[:n], cog.new[:n])
    same_named = sum(a == b for a, b in zip(named_o, named_c, strict=True)) / n
    same_new = sum(a == b for a, b in zip(ors.new[:n], cog.new[:n], strict=True)) / n
    same_action = sum(ors.action.get(i, 0) == cog.action.get(i, 0) for i in range(n)) / n
    first = next((i for i in range(n) if ors.vt[i] != cog.vt[i]), None)
    both = [i for i in ors.peak if i in cog.peak]
    diffs = [peak_difference(ors.peak[i], cog.peak[i]) for i in both]
    peak_err = max(diffs, default=0.0)
    same_peak = sum(d < 1e-6 for d in diffs) / max(1, len(diffs))
    exp_diff = abs(cog.experiences - ors.experiences) / max(1, ors.experiences)
    link_diff = abs(cog.links - ors.links) / max(1, ors.links)
    speed = (ors.seconds / n) / (cog.seconds / n)
    print(f"{label}: {n} frames")
    print(
        f"  same view template {100 * same_vt:.2f} % of frames (named by creating frame "
        f"{100 * same_named:.2f} %), same new-or-matched {100 * same_new:.2f} %, first "
        f"difference at frame {first}"
    )
    print(
        f"  templates: OpenRatSLAM {max(ors.vt[:n]) + 1}, cogmap {max(cog.vt[:n]) + 1}; same "
        f"action {100 * same_action:.2f} % of frames; pose-cell peak at the actions both take "
        f"equal (< 1e-6 cells) on {100 * same_peak:.2f} %, largest difference {peak_err:.3g} cells"
    )
    print(
        f"  experiences: OpenRatSLAM {ors.experiences}, cogmap {cog.experiences} "
        f"({100 * exp_diff:.2f} % apart); links: {ors.links} vs {cog.links} "
        f"({100 * link_diff:.2f} % apart)"
    )
    print(
        f"  front-end time: OpenRatSLAM {1e3 * ors.seconds / n:.3f} ms/frame, cogmap "
        f"{1e3 * cog.seconds / n:.3f} ms/frame: cogmap {speed:.1f} x faster (wall time)"
    )
    if ors.cpu_seconds == ors.cpu_seconds:  # the driver reports CPU time
        print(
            f"  front-end CPU time: OpenRatSLAM {1e3 * ors.cpu_seconds / n:.3f} ms/frame, cogmap "
            f"{1e3 * cog.cpu_seconds / n:.3f} ms/frame: cogmap "
            f"{ors.cpu_seconds / cog.cpu_seconds:.1f} x faster (load average "
            f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)"
        )
    ok = same_vt >= 0.99 and exp_diff <= 0.01 and link_diff <= 0.01
    print(f"  targets (>= 99 % same template, counts within 1 %): {'met' if ok else 'NOT met'}")
    return {
        "same_vt": same_vt,
        "same_named": same_named,
        "exp_diff": exp_diff,
        "link_diff": link_diff,
        "speed": speed,
    }


def default_bags(folder: Path) -> list[Path]:
    """The default dataset and the figure-eight layout (generated once into ``folder``)."""
    bags = [default_dataset_path()]
    other = folder / "figure_eight_6laps_seed1.bag"
    if not other.exists():
        folder.mkdir(parents=True, exist_ok=True)
        generate_maze_bag(other, MazeConfig(layout="figure_eight"), overwrite=True)
    bags.append(other)
    return bags


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--driver", type=Path, required=True, help="OpenRatSLAM driver program")
    parser.add_argument("--bag", type=Path, action="append", help="bag(s) to compare")
    parser.add_argument(
        "--settings", nargs="+", choices=sorted(SETTINGS), default=["irat", "profile"]
    )
    parser.add_argument("--frames", type=int, default=None, help="first N frames only")
    parser.add_argument("--keep", type=Path, default=None, help="folder for generated bags")
    args = parser.parse_args()
    if not os.access(args.driver, os.X_OK):
        print(f"{args.driver}: not an executable driver", file=sys.stderr)
        return 2
    bags = args.bag or default_bags(args.keep or cache_dir())
    failures = 0
    with tempfile.TemporaryDirectory(prefix="cogmap-ors-") as tmp:
        for bag in bags:
            stream = Path(tmp) / "stream.bin"
            frames, shape = write_stream(bag, stream, args.frames)
            for name in args.settings:
                config = FrontEndConfig().with_changes(**SETTINGS[name])
                ini = Path(tmp) / "config.ini"
                write_config(ini, config, shape)
                ors = run_driver(args.driver, ini, stream)
                cog = run_cogmap(bag, config, args.frames)
                result = compare(f"{bag.name}, {name} settings", ors, cog)
                met = result["same_vt"] >= 0.99 and max(result["exp_diff"], result["link_diff"])
                failures += not (met and max(result["exp_diff"], result["link_diff"]) <= 0.01)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
