"""Slider release -> updated map latency of the web app, on the default dataset at its end.

Drives the server the way a browser does (the slider handles' values are set, which runs the
same callbacks as a client's update): replays the whole bag at maximum speed, then for each map
shown (compact, scene_integration, standard) moves a slider that changes that map (delta for the
compact map, which is the only one it affects; T_interval for every map) to a few values and
reports the time from the slider change to the displayed map being published to the scene (and
to all three maps being up to date), against the 200 ms target. Finally a slider storm (many
changes per second) checks that work never queues: how many rebuilds started, how many were
abandoned, and how long after the last change the final map was shown.

    python benchmarks/slider_latency.py [BAG] [--storm N]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import viser  # noqa: E402

from app.cli_common import resolve_bag  # noqa: E402
from app.server.app import CogmapApp  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402

TARGET_S = 0.200
#: (shown map, slider, values): each value is a change that map must be rebuilt for.
CASES: tuple[tuple[MapMode, str, tuple[float, ...]], ...] = (
    (MapMode.COMPACT, "delta", (5.0, 3.746, 8.0, 4.5)),
    (MapMode.COMPACT, "t_interval", (3.0, 2.0)),
    (MapMode.SCENE_INTEGRATION, "t_interval", (3.0, 2.0, 1.0)),
    (MapMode.STANDARD, "t_interval", (3.0, 2.0, 1.0)),
    (MapMode.STANDARD, "delta", (5.0, 3.746)),
)


def wait_rebuilt(app: CogmapApp, count: int, timeout: float = 600.0) -> None:
    """Wait until ``count`` rebuild records exist and the worker is idle."""
    deadline = time.monotonic() + timeout
    while len(app.replay.rebuilds) < count and time.monotonic() < deadline:
        time.sleep(0.002)
    if not app.replay.wait_idle(timeout):
        raise SystemExit("the server did not become idle")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", default=None, help="bag (default: built-in dataset)")
    parser.add_argument("--storm", type=int, default=60, help="slider events in the storm")
    args = parser.parse_args()
    bag = resolve_bag(args.bag)  # default: the built-in dataset
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8090, verbose=False)
    app = CogmapApp(server, bag, speed=math.inf)
    started = time.perf_counter()
    app.start()
    if not app.replay.wait_idle(3600):
        raise SystemExit("replay did not finish")
    replay = app.replay
    print(f"bag: {bag}")
    print(
        f"replayed {replay.cursor} frames ({replay.duration:.0f} s of data) in "
        f"{time.perf_counter() - started:.1f} s; state {replay.state.value} {replay.message}"
    )
    sizes = {m.value: replay.session.maps[m].num_vertices for m in MapMode}
    events = len(replay.session.log.events)
    print(f"maps at the end (vertices): {sizes}; cached events: {events}")
    print()
    header = (
        f"{'shown map':18} {'slider':>10} {'value':>6} {'shown ms':>9} {'x target':>8} "
        f"{'all 3 ms':>9} {'rebuild ms (std / si / compact)':>32}"
    )
    print(header)
    results: dict[tuple[MapMode, str], list[float]] = {}
    for mode, name, values in CASES:
        app.mode_dropdown.value = mode.value
        for value in values:
            n = len(replay.rebuilds)
            app.param_sliders[name].value = value
            wait_rebuilt(app, n + 1)
            record = replay.rebuilds[-1]
            shown = record.latency(mode)
            assert shown is not None and record.completed
            total = max(record.published.values()) - record.requested
            compute = " / ".join(
                f"{record.compute_s[m] * 1000:.0f}"
                for m in (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)
            )
            results.setdefault((mode, name), []).append(shown)
            print(
                f"{mode.value:18} {name:>10} {value:6.3f} {shown * 1000:9.1f} "
                f"{shown / TARGET_S:8.2f} {total * 1000:9.1f} {compute:>32}"
            )
    print("(rebuild 0 ms: the parameter does not affect that map, which is kept as it is)")
    print()
    for (mode, name), values in results.items():
        med = statistics.median(values)
        print(
            f"median slider->shown latency, {mode.value:18} ({name:10}): {med * 1000:7.1f} ms "
            f"({med / TARGET_S:.2f} x the {TARGET_S * 1000:.0f} ms target)"
        )

    # storm: many changes per second, latest wins
    app.mode_dropdown.value = MapMode.COMPACT.value
    slider = app.param_sliders["delta"]
    n_before = len(replay.rebuilds)
    values = [3.0 + 0.05 * k for k in range(args.storm)]
    t0 = time.perf_counter()
    for v in values:
        slider.value = v
        time.sleep(1.0 / 30.0)  # 30 events per second, like a dragged slider
    last_change = time.perf_counter()
    replay.wait_idle(600)
    records = replay.rebuilds[n_before:]
    final = records[-1]
    assert final.completed and math.isclose(final.params.delta, values[-1])
    shown_after = final.published[MapMode.COMPACT] - last_change
    print()
    print(
        f"storm: {len(values)} slider events in {last_change - t0:.2f} s -> "
        f"{len(records)} rebuilds started, {sum(not r.completed for r in records)} abandoned, "
        f"final delta {final.params.delta:.3f} == last value; final compact map shown "
        f"{shown_after * 1000:.0f} ms after the last event"
    )
    app.stop()
    server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
