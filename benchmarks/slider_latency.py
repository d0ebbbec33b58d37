"""Slider change -> shown map updated: every map, every tuning slider, default and long bags.

Drives the server the way a browser does: a value is typed into a parameter's box (the same
callback a client's message runs), and the time from that change to the displayed map being
handed to the scene is measured (``RebuildRecord.latency``), with the time until all three maps
are up to date. The maps are built from the front end's events in the user-wide event cache
(made once with the front end if missing), as the app's replay cache holds them after a first
pass: the app is loaded with them, put at the end of the data and every measurement starts from
there.

For each shown map (compact, scene_integration, standard) and each of the five sliders (alpha,
beta, delta, T_interval, T_total) it types ``--values`` values never used before (no cache hit;
the cache is emptied between shown maps), then the paper's values back. It reports the median
latency per map and slider against the 200 ms target, how each map was obtained (built in a
worker process, kept because the change does not affect it or leaves its cluster schedule as
it was, or taken from the cache; "resumed" when a T_interval or T_total rebuild continued
from the map's state at the last cluster its schedule shares with the map before), the cost of
returning to values met before (the cache), a slider storm (many changes per second: work never
queues), and the same table on a long bag (``--long BAG``, e.g. a 60-lap bag from
``cogmap make-maze BAG --laps 60``) against 2 s (issue 27).

Two latencies per change (issue 27 part 4, :mod:`app.server.preview`): the *exact* one, until
the map ``cogmap run`` gives for the new values is shown (``RebuildRecord.latency``), and the
*preview* one, until a first map is shown (``RebuildRecord.preview_latency``): where the shown
map's last build took longer than ``PREVIEW_AFTER_S`` (200 ms), the app first draws a preview
-- the map shown before for a T_interval or T_total change, the compact map re-derived from the
standard map for an alpha, beta or delta change -- and the exact map when it is built; without a
preview (a fast map, a kept or cached one, any other change) the preview latency is the exact
one. The difference of each preview to its exact map (largest vertex shift, vertices) is
reported beside it.

    python benchmarks/slider_latency.py [BAG] [--values 3] [--long BAG] [--storm 60]

The last line reads ``worst median latency: N ms exact, M ms preview (MAP, SLIDER)`` (the
default dataset; N the worst median exact latency over maps and sliders, M the worst median
preview latency, the map and slider those of the exact one).
"""

from __future__ import annotations

import argparse
import array
import contextlib
import io
import math
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import viser  # noqa: E402

from app.cli_common import resolve_bag  # noqa: E402
from app.events_cache import cached_bag_events  # noqa: E402
from app.server.app import CogmapApp  # noqa: E402
from app.server.replay import PlaybackState, RebuildRecord  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402
from cogmap_core.config import MapParams  # noqa: E402
from cogmap_core.event_log import EventLog  # noqa: E402
from cogmap_core.map_modes import ALL_MODES  # noqa: E402
from cogmap_core.parameter_table import PARAMETERS  # noqa: E402

TARGET_S = 0.200
LONG_TARGET_S = 2.0  # issue 27: exact map within 2 s on 60 laps
MODES = (MapMode.COMPACT, MapMode.SCENE_INTEGRATION, MapMode.STANDARD)
ORDER = ALL_MODES
#: Fresh values per slider (the paper's: alpha = beta = 10, delta = 3.746, 2 s, 100 s).
VALUES: dict[str, tuple[float, ...]] = {
    "alpha": (20.0, 5.0, 40.0, 15.0, 30.0),
    "beta": (20.0, 5.0, 40.0, 15.0, 30.0),
    "delta": (5.0, 8.0, 4.5, 6.0, 3.0),
    "t_interval": (3.0, 1.0, 2.5, 4.0, 1.5),
    "t_total": (50.0, 30.0, 70.0, 20.0, 60.0),
}
SHORT = {name: PARAMETERS[name].label for name in VALUES}  # the sliders' labels


def loaded_app(bag: Path, port: int) -> tuple[CogmapApp, viser.ViserServer]:
    """The app with the bag's events in its replay cache, at the end of the data, paused."""
    recording = cached_bag_events(bag, print)
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    app = CogmapApp(server, bag, speed=math.inf, autoplay=False)
    log = EventLog.from_recording(recording)
    app.replay.session.log = log  # what the first pass would have cached
    app.replay.view_templates = array.array("q", [-1] * log.frames)  # (-1: none known)
    started = time.perf_counter()
    app.start()
    replay = app.replay
    wait_for(lambda: replay.state is PlaybackState.PAUSED, 600)
    replay.seek(log.frame_time[-1])  # builds the three maps from the cached events
    wait_idle(app)
    replay.play()  # the few frames after the last cached one, then the end of the data
    wait_idle(app)
    if replay.state is not PlaybackState.ENDED or replay.cursor != log.frames:
        raise SystemExit(f"could not load {bag}: {replay.state.value} {replay.message}")
    sizes = ", ".join(f"{m.value} {replay.session.maps[m].num_vertices}" for m in ORDER)
    print(
        f"{bag.name}: {log.frames} frames, {log.frame_time[-1]:.0f} s of data, "
        f"{len(log.events)} events; maps built in {time.perf_counter() - started:.1f} s "
        f"(vertices: {sizes}); rebuild workers: {replay.builder.workers}"
    )
    return app, server


def wait_for(condition: object, timeout: float) -> None:
    """Poll ``condition()`` until true."""
    deadline = time.monotonic() + timeout
    while not condition():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise SystemExit("timed out")
        time.sleep(0.002)


def wait_idle(app: CogmapApp, timeout: float = 3600.0) -> None:
    """Wait until the worker has nothing left to do."""
    if not app.wait_idle(timeout):
        raise SystemExit("the server did not become idle")


def change(app: CogmapApp, name: str, value: float) -> RebuildRecord:
    """Type ``value`` into the parameter's box and wait for the rebuild it starts."""
    n = len(app.replay.rebuilds)
    app.type_param(name, repr(value))
    wait_for(lambda: len(app.replay.rebuilds) > n, 600)
    wait_idle(app)
    record = app.replay.rebuilds[-1]
    assert record.completed and getattr(record.params, name) == value, record
    return record


def back_to_paper(app: CogmapApp) -> None:
    """Reset to the paper's values (maps from the cache; not measured)."""
    if app.replay.params != MapParams():
        app.reset_params()
        wait_idle(app)


Results = dict[tuple[MapMode, str], list[tuple[float, float]]]
"""Per shown map and slider, (exact, preview) latencies (s)."""


def measure(app: CogmapApp, count: int, label: str) -> Results:
    """The table for one bag: every shown map x every slider x ``count`` fresh values."""
    results: Results = {}
    hows: dict[tuple[MapMode, str], set[str]] = {}
    print()
    print(f"{label}: slider change -> shown map updated (preview: first map shown; its difference)")
    print(
        f"{'shown map':18} {'slider':>10} {'value':>7} {'exact ms':>9} {'preview':>8} "
        f"{'all 3 ms':>9}  {'rebuild ms and how (standard / scene_integration / compact)'}"
    )
    for mode in MODES:
        app.show_maps(mode)
        app.replay.cache.clear()  # every value below is new to this shown map
        for name, values in VALUES.items():
            for value in values[:count]:
                record = change(app, name, value)
                shown = record.latency(mode)
                first = record.preview_latency(mode)
                assert shown is not None and first is not None
                total = max(record.published.values()) - record.requested
                how = " / ".join(
                    f"{record.compute_s[m] * 1000:5.0f} {obtained(record, m):7}" for m in ORDER
                )
                results.setdefault((mode, name), []).append((shown, first))
                hows.setdefault((mode, name), set()).add(obtained(record, mode))
                print(
                    f"{mode.value:18} {SHORT[name]:>10} {value:7.3f} {shown * 1000:9.1f} "
                    f"{first * 1000:8.1f} {total * 1000:9.1f}  {how}{differed(record, mode)}"
                )
            back_to_paper(app)
    print()
    print(
        f"{label}: median latency (ms) per map and slider, exact / preview (no preview: the "
        "exact map comes first), how the shown map was obtained"
    )
    print(f"{'slider':>10} " + " ".join(f"{m.value:>34}" for m in MODES))
    for name in VALUES:
        cells = []
        for mode in MODES:
            exact = statistics.median(e for e, _ in results[(mode, name)]) * 1000
            first = statistics.median(p for _, p in results[(mode, name)]) * 1000
            ways = "/".join(sorted(hows[(mode, name)]))
            cells.append(f"{exact:7.0f} / {first:5.0f} ({ways:>16})")
        print(f"{SHORT[name]:>10} " + " ".join(f"{c:>34}" for c in cells))
    return results


def differed(record: RebuildRecord, mode: MapMode) -> str:
    """How far the shown map's preview was from its exact map (empty: no preview)."""
    if mode not in record.previewed:
        return ""
    difference = record.preview_difference.get(mode)
    if difference is None:
        return "  (preview)"
    shift, count = difference
    return f"  (preview: {shift * 1000:.0f} mm, {count:+d} vertices)"


def obtained(record: RebuildRecord, mode: MapMode) -> str:
    """How a rebuild obtained a map: built, resumed (from a cluster's state), kept, cached."""
    if record.how[mode] == "built" and record.resumed.get(mode, 0) > 0:
        return "resumed"
    return record.how[mode]


def revisit(app: CogmapApp) -> None:
    """A value met before comes from the cache."""
    app.show_maps(MapMode.STANDARD)
    change(app, "t_interval", 3.0)
    back_to_paper(app)
    record = change(app, "t_interval", 3.0)
    shown = record.latency(MapMode.STANDARD)
    assert shown is not None
    print(
        f"back to a value met before (T_interval 3, standard shown): {shown * 1000:.1f} ms "
        f"({', '.join(f'{m.value} {obtained(record, m)}' for m in ORDER)})"
    )
    back_to_paper(app)


def storm(app: CogmapApp, count: int) -> None:
    """Many changes per second: work never queues, the last value wins."""
    app.show_maps(MapMode.COMPACT)
    n_before = len(app.replay.rebuilds)
    values = [3.0 + 0.05 * k for k in range(count)]
    t0 = time.perf_counter()
    for v in values:
        app.param_sliders["delta"].value = v
        time.sleep(1.0 / 30.0)  # 30 events per second, like a dragged slider
    last_change = time.perf_counter()
    wait_idle(app)
    records = app.replay.rebuilds[n_before:]
    final = records[-1]
    assert final.completed and math.isclose(final.params.delta, values[-1])
    shown_after = final.published[MapMode.COMPACT] - last_change
    print(
        f"storm: {len(values)} slider events in {last_change - t0:.2f} s -> "
        f"{len(records)} rebuilds started, {sum(not r.completed for r in records)} abandoned, "
        f"final delta {final.params.delta:.3f} == last value; final compact map shown "
        f"{shown_after * 1000:.0f} ms after the last event"
    )
    back_to_paper(app)


def worst(results: Results, which: int = 0) -> tuple[float, MapMode, str]:
    """The worst median over maps and sliders: of the exact latency (``which`` 0) or preview (1)."""
    return max(
        (statistics.median(pair[which] for pair in v), m, n) for (m, n), v in results.items()
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", default=None, help="bag (default: built-in dataset)")
    parser.add_argument("--values", type=int, default=3, help="fresh values per slider (1-5)")
    parser.add_argument("--long", default=None, metavar="BAG", help="a long bag (e.g. 60 laps)")
    parser.add_argument("--long-values", type=int, default=1, help="values per slider, long bag")
    parser.add_argument("--storm", type=int, default=60, help="slider events in the storm")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the start")
    bag = resolve_bag(args.bag)
    app, server = loaded_app(bag, 8090)
    try:
        results = measure(app, args.values, "default dataset")
        print()
        revisit(app)
        storm(app, args.storm)
    finally:
        app.stop()
        server.stop()
    long_results = None
    if args.long:
        app, server = loaded_app(Path(args.long), 8091)
        try:
            long_results = measure(app, args.long_values, Path(args.long).name)
        finally:
            app.stop()
            server.stop()
    print()
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    if long_results is not None:
        med, mode, name = worst(long_results)
        first, pmode, pname = worst(long_results, 1)
        print(
            f"long bag worst median latency: {med * 1000:.0f} ms exact ({mode.value}, "
            f"{SHORT[name]}), {first * 1000:.0f} ms preview ({pmode.value}, {SHORT[pname]}); "
            f"target {LONG_TARGET_S * 1000:.0f} ms"
        )
    med, mode, name = worst(results)
    first, pmode, pname = worst(results, 1)
    if (pmode, pname) != (mode, name):
        print(
            f"worst median preview latency: {first * 1000:.0f} ms ({pmode.value}, {SHORT[pname]})"
        )
    print(
        f"worst median latency: {med * 1000:.0f} ms exact, {first * 1000:.0f} ms preview "
        f"({mode.value}, {SHORT[name]})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
