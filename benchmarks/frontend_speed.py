"""Speed of the SLAM front end: per-frame cost with thousands of templates, fast vs exhaustive.

Usage::

    python benchmarks/frontend_speed.py [--templates 2000] [--scale 1] [--laps 2] [--bag BAG]

Without ``--bag`` a synthetic stream is used: a robot drives laps of a closed circuit whose walls
are a long panorama of textured segments with landmarks (rendered at 1/``scale`` of the iRat's
416x240; the headless pipeline decodes JPEGs at full size), with sensor noise and light
changes. The first lap is exploration (mostly new templates); the later laps revisit it, with
loop closures. The circuit is long enough that the first lap stores about ``--templates``
templates. With ``--bag`` the frames of a bag are used instead (through the dataset reader).

Printed: per-frame front-end cost (mean, median, p95) per lap and per part (template extraction,
matching, the rest: pose cells and actions); then, on a sample of frames from the last lap, the
pruned matcher against the exhaustive search: identical results, time per query and the speed-up
ratio.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterator

import cv2
import numpy as np

from cogmap_core.events import CreateVertex, LinkToVertex
from cogmap_core.frames import Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig

FPS = 17.5
STEP_M = 0.01  # forward motion per frame (0.175 m/s)
PX_PER_STEP = 12  # panorama pixels (full scale) passed per frame


def make_panorama(length: int, height: int, seed: int) -> np.ndarray:
    """A long strip of wall: segments of varied brightness and texture, with landmarks."""
    rng = np.random.default_rng(seed)
    wall = np.zeros((height, length), np.float32)
    x = 0
    while x < length:
        seg = int(rng.integers(80, 400))
        wall[:, x : x + seg] = rng.uniform(0.25, 0.75)
        for _ in range(int(rng.integers(1, 4))):
            cx, cy = x + int(rng.integers(0, seg)), int(rng.integers(0, height))
            cv2.circle(wall, (cx, cy), int(rng.integers(10, 60)), float(rng.uniform(0, 1)), -1)
        x += seg
    wall += rng.normal(0.0, 0.08, wall.shape).astype(np.float32)
    wall = cv2.GaussianBlur(wall, (0, 0), 3)
    wall *= np.linspace(0.8, 1.1, height, dtype=np.float32)[:, None]  # floor-to-ceiling light
    return np.clip(wall, 0.0, 1.0)


def synthetic_frames(templates: int, laps: int, scale: int, seed: int = 0) -> Iterator[Frame]:
    """Frames of ``laps`` laps of a circuit sized to give about ``templates`` templates."""
    steps = max(100, int(templates * 5.3))  # frames per lap (about 1 template per 5.3 frames)
    length = steps * PX_PER_STEP
    pano = make_panorama(length, 240, seed)
    width, height = 416 // scale, 240 // scale
    small = cv2.resize(pano, (length // scale, height), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(seed + 1)
    turn = 2.0 * math.pi / steps  # a closed circuit
    index = 0
    for _ in range(laps):
        for step in range(steps):
            start = (step * PX_PER_STEP + int(rng.integers(-3, 4))) // scale
            cols = (np.arange(width) + start) % small.shape[1]
            light = 1.0 + 0.03 * math.sin(index / 500.0)
            image = small[:, cols] * (255.0 * light) + rng.normal(0.0, 2.0, (height, width))
            yield Frame(
                index,
                index / FPS,
                np.clip(image, 0, 255).astype(np.uint8),
                STEP_M,
                turn,
            )
            index += 1


def bag_frames(path: str, scale: int) -> Iterator[Frame]:
    """Frames of a bag, through the dataset reader."""
    from cogmap_core.datasets import open_bag

    yield from open_bag(path, image_scale=scale).frames()


def stats(values: list[float]) -> str:
    """Mean, median and 95th percentile in microseconds."""
    a = np.asarray(values) * 1e6
    return f"mean {a.mean():7.1f}  median {np.median(a):7.1f}  p95 {np.percentile(a, 95):7.1f} us"


def main() -> None:
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--templates", type=int, default=2000, help="templates after lap 1")
    parser.add_argument("--laps", type=int, default=2)
    parser.add_argument("--scale", type=int, default=1, choices=(1, 2, 4))
    parser.add_argument("--bag", help="use the frames of this bag instead")
    parser.add_argument("--sample", type=int, default=200, help="frames for fast vs exhaustive")
    args = parser.parse_args()

    frames = list(
        bag_frames(args.bag, args.scale)
        if args.bag
        else synthetic_frames(args.templates, args.laps, args.scale)
    )
    lap_length = len(frames) // (1 if args.bag else args.laps)
    fe = FrontEnd(FrontEndConfig())
    lv = fe.local_view
    clock = time.process_time  # CPU time of this process: robust to other load on the machine
    total: list[float] = []
    wall: list[float] = []
    extract: list[float] = []
    matching: list[float] = []
    links = creates = 0
    for frame in frames:
        w0, t0 = time.perf_counter(), clock()
        events = fe.process(frame)
        total.append(clock() - t0)
        wall.append(time.perf_counter() - w0)
        # The parts, re-timed on the same input (extraction and matching are pure functions).
        t1 = clock()
        template = lv.make_template(frame.image)
        t2 = clock()
        lv.match(template, fe.current_template)
        t3 = clock()
        extract.append(t2 - t1)
        matching.append(t3 - t2)
        links += sum(isinstance(e, LinkToVertex) for e in events)
        creates += sum(isinstance(e, CreateVertex) for e in events)

    print(f"front end on {len(frames)} frames of {frames[0].image.shape[::-1]} px (CPU time)")
    print(f"templates {fe.template_count}, vertices {creates}, loop-closure links {links}")
    for lap in range(math.ceil(len(frames) / lap_length)):
        part = slice(lap * lap_length, (lap + 1) * lap_length)
        print(f"lap {lap + 1}: per frame    {stats(total[part])}")
    last = slice(len(frames) - lap_length, len(frames))
    print(f"last lap: extraction {stats(extract[last])}")
    print(f"last lap: matching   {stats(matching[last])} (hint: the previous frame's template)")
    rest = [t - e - m for t, e, m in zip(total[last], extract[last], matching[last], strict=True)]
    print(f"last lap: the rest (pose cells, actions) {stats(rest)}")
    print(f"all frames, wall clock: {stats(wall)}")
    budget = np.mean(total) * FPS
    print(
        f"front-end CPU time per second of data at {FPS} Hz: {budget:.4f} s "
        f"({1 / budget:.0f}x real time)"
    )

    # Fast vs exhaustive on a sample of the last lap's views.
    rng = np.random.default_rng(0)
    sample = min(args.sample, lap_length)
    picks = rng.choice(np.arange(last.start, last.stop), size=sample, replace=False)
    fast_t: list[float] = []
    slow_t: list[float] = []
    same = 0
    candidates = []
    for i in sorted(picks):
        template = lv.make_template(frames[i].image)
        t0 = clock()
        fast = lv.match(template)  # no hint: the bound is the threshold alone
        t1 = clock()
        slow = lv.match_exhaustive(template)
        t2 = clock()
        fast_t.append(t1 - t0)
        slow_t.append(t2 - t1)
        candidates.append(fast.candidates)
        same += (fast.template_id, fast.offset, fast.sad) == (
            slow.template_id,
            slow.offset,
            slow.sad,
        )
    pairs = lv.count * len(lv.config.shifts)
    print(
        f"matcher on {sample} views, {lv.count} templates x {len(lv.config.shifts)} shifts "
        f"= {pairs} pairs:"
    )
    print(f"  exhaustive {stats(slow_t)}")
    print(f"  pruned     {stats(fast_t)} (no hint)")
    print(f"  exact SADs computed by the pruned search: mean {np.mean(candidates):.1f} of {pairs}")
    print(f"  identical results: {same}/{sample}")
    print(f"  speed-up (exhaustive / pruned, mean): {np.mean(slow_t) / np.mean(fast_t):.0f}x")


if __name__ == "__main__":
    main()
