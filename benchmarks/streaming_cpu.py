"""Server-side CPU of streaming the maps, at 1x playback, and the cost of a 10,000-vertex map.

Part 1 replays the default dataset (or BAG) through the web app: it runs as fast as possible to
``--window`` seconds before the end (not measured), then plays at 1x for ``--window`` seconds of
data with ``--clients`` browsers' worth of websocket clients draining the stream (in another
process, so their CPU is not counted). It reports the process's CPU split into the SLAM work
(front end + maps, on the worker thread) and the streaming (the page updates made on the worker
thread plus every other thread: viser's event loop, serialisation, sending), as a percentage of
one core, against the 20% target. Then a client joins late and the time and bytes until it holds
the full page are reported.

Part 2 streams a synthetic 10,000-vertex standard map growing at 17.5 vertices per second, as the
app does at 1x (10 updates per second), and reports the cost of an ordinary update (only the last
chunks change), of the full re-send after an optimisation, and the streaming CPU.

    python benchmarks/streaming_cpu.py [BAG] [--window 60] [--clients 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import viser  # noqa: E402

from app.server.app import CogmapApp  # noqa: E402
from app.server.scene import SceneStreamer  # noqa: E402
from cogmap_core.cognitive_map import CognitiveMap, MapMode  # noqa: E402
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry  # noqa: E402

TARGET = 0.20

DRAIN = r"""
import sys, time, threading, viser
from websockets.sync.client import connect
port, clients, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
total = [0] * clients
def run(i):
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                 max_size=None) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                total[i] += len(ws.recv(timeout=0.5))
            except TimeoutError:
                pass
threads = [threading.Thread(target=run, args=(i,)) for i in range(clients)]
[t.start() for t in threads]
[t.join() for t in threads]
print(sum(total))
"""


def thread_cpu(thread: threading.Thread) -> float:
    """CPU seconds used by ``thread`` so far."""
    assert thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


class TimedListener:
    """Wraps the app's listener methods to count the worker-thread CPU spent in them."""

    def __init__(self, app: CogmapApp) -> None:
        self.cpu = 0.0
        for name in ("on_status", "on_frame", "on_maps"):
            original = getattr(app, name)

            def timed(*args: Any, _original: Any = original) -> None:
                started = time.thread_time()
                try:
                    _original(*args)
                finally:
                    self.cpu += time.thread_time() - started

            setattr(app, name, timed)


def drain(port: int, clients: int, seconds: float) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", DRAIN, str(port), str(clients), str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )


def late_join(port: int, quiet: float = 1.0) -> tuple[float, int]:
    """Seconds until a new client has received everything (no message for ``quiet`` s), bytes."""
    from websockets.sync.client import connect

    started = time.perf_counter()
    size = 0
    last = started
    with connect(
        f"ws://127.0.0.1:{port}",
        subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
        max_size=None,
    ) as ws:
        while True:
            try:
                size += len(ws.recv(timeout=quiet))
                last = time.perf_counter()
            except TimeoutError:
                break
    return last - started, size


def part1(bag: Path, window: float, clients: int) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8091, verbose=False)
    app = CogmapApp(server, bag, speed=math.inf, autoplay=False)
    listener = TimedListener(app)
    app.start()
    replay = app.replay
    assert replay.wait_idle(600)
    start = max(0.0, replay.duration - window - 5.0)
    t0 = time.perf_counter()
    replay.seek(start)
    replay.play()
    while replay.frame_time < start and replay.state.value != "error":
        time.sleep(0.05)
    replay.pause()
    assert replay.wait_idle(600)
    print(f"bag: {bag}")
    print(
        f"fast-forward to t = {replay.frame_time:.1f} s ({replay.cursor} frames) took "
        f"{time.perf_counter() - t0:.1f} s; maps: "
        + ", ".join(f"{m.value} {replay.session.maps[m].num_vertices} V" for m in MapMode)
    )
    app.show_maps(MapMode.STANDARD, MapMode.COMPACT)  # the biggest map beside the compact one
    worker = replay._thread
    assert worker is not None
    drainer = drain(server.get_port(), clients, window + 3.0)
    time.sleep(1.5)
    app.speed_dropdown.value = "1x"
    cpu0, worker0, listen0, wall0 = time.process_time(), thread_cpu(worker), listener.cpu, 0.0
    stats0 = app.streamer.stats.copy()
    wall0 = time.perf_counter()
    frames0 = replay.cursor
    replay.play()
    time.sleep(window)
    cpu1, worker1, listen1 = time.process_time(), thread_cpu(worker), listener.cpu
    wall = time.perf_counter() - wall0
    stats1 = app.streamer.stats.copy()
    replay.pause()
    received = int(drainer.communicate()[0].strip() or 0)
    total = (cpu1 - cpu0) / wall
    worker_cpu = (worker1 - worker0) / wall
    listen = (listen1 - listen0) / wall
    streaming = listen + (total - worker_cpu)
    slam = worker_cpu - listen
    print(
        f"1x playback for {wall:.1f} s ({replay.cursor - frames0} frames, standard and compact "
        f"shown, {clients} clients): {stats1.updates - stats0.updates} scene updates, "
        f"{stats1.chunks_sent - stats0.chunks_sent} chunks, "
        f"{(stats1.bytes_sent - stats0.bytes_sent) / 1e6:.2f} MB of geometry; clients received "
        f"{received / 1e6:.2f} MB"
    )
    print(f"  process CPU             {total * 100:6.1f} % of one core")
    print(f"  SLAM (front end + maps) {slam * 100:6.1f} %")
    print(
        f"  streaming               {streaming * 100:6.1f} %  (page updates {listen * 100:.1f} % "
        f"+ viser threads {(total - worker_cpu) * 100:.1f} %)  -> {streaming / TARGET:.2f} x "
        f"the {TARGET * 100:.0f} % target"
    )
    seconds, size = late_join(server.get_port())
    print(
        f"late join: a new client holds the full page after {seconds * 1000:.0f} ms "
        f"({size / 1e6:.2f} MB)"
    )
    app.stop()
    server.stop()


def synthetic_events(vertices: int, laps: int) -> list[MapEvent]:
    """Laps of a 20 m circle with drifting odometry, one vertex per step; later laps close loops
    on the first lap's vertices every 10 vertices (so optimisations move the whole map)."""
    per_lap = vertices // laps
    rng = np.random.default_rng(1)
    events: list[MapEvent] = []
    for k in range(vertices):
        t = k / 17.5
        turn = 2 * math.pi / per_lap * (1.0 + 0.02 + 0.01 * rng.standard_normal())
        events.append(Odometry(t, 20.0 / per_lap, turn))
        events.append(CreateVertex(t, k, k))
        if k >= per_lap and k % 10 == 0:
            events.append(LinkToVertex(t, k % per_lap, 0.0))
    return events


def part2(seconds: float) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=8092, verbose=False)
    streamer = SceneStreamer(server)
    streamer.show((MapMode.STANDARD,))
    n0 = 10_000
    extra = int(17.5 * seconds) + 1
    events = synthetic_events(n0 + extra, laps=1)  # one lap: no loop closes yet
    cmap = CognitiveMap(MapMode.STANDARD)
    head = 2 * n0
    cmap.apply_all(events[:head])
    drainer = drain(server.get_port(), 1, seconds + 6.0)
    time.sleep(1.5)
    started = time.perf_counter()
    streamer.publish({MapMode.STANDARD: cmap})
    first = time.perf_counter() - started
    first_bytes = streamer.stats.bytes_sent
    cpu0 = time.process_time()
    wall0 = time.perf_counter()
    costs: list[float] = []
    sizes: list[int] = []
    done = head
    for k in range(int(10 * seconds)):  # 10 updates per second, 1.75 new vertices each
        due = wall0 + (k + 1) / 10.0
        target = head + int(2 * 17.5 * (k + 1) / 10.0)
        cmap.apply_all(events[done:target])
        done = target
        before = streamer.stats.bytes_sent
        t = time.perf_counter()
        streamer.publish({MapMode.STANDARD: cmap})
        costs.append(time.perf_counter() - t)
        sizes.append(streamer.stats.bytes_sent - before)
        time.sleep(max(0.0, due - time.perf_counter()))
    wall = time.perf_counter() - wall0
    cpu = (time.process_time() - cpu0) / wall
    cmap.apply_all(events[done:])
    last = events[-1].time
    cmap.apply(LinkToVertex(last, 0, 0.0))  # back at the start: a loop closure ...
    cmap.optimize_now()  # ... and its optimisation: every vertex moves
    assert cmap.optimizations
    before = streamer.stats.bytes_sent
    t = time.perf_counter()
    streamer.publish({MapMode.STANDARD: cmap})
    full = time.perf_counter() - t
    full_bytes = streamer.stats.bytes_sent - before
    drainer.communicate()
    print()
    print(
        f"synthetic standard map, {n0} -> {cmap.num_vertices} vertices at 17.5 vertices/s, "
        f"10 updates/s for {wall:.1f} s:"
    )
    print(
        f"  first (full) send {first * 1000:.1f} ms, {first_bytes / 1e6:.2f} MB; ordinary update "
        f"median {statistics.median(costs) * 1000:.2f} ms, max {max(costs) * 1000:.2f} ms, "
        f"median {statistics.median(sizes) / 1e3:.1f} kB"
    )
    print(f"  full re-send after an optimisation: {full * 1000:.1f} ms, {full_bytes / 1e6:.2f} MB")
    print(
        f"  streaming CPU (process, with one client draining): {cpu * 100:.1f} % of one core "
        f"-> {cpu / TARGET:.2f} x the {TARGET * 100:.0f} % target"
    )
    server.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", default=None, help="bag (default: built-in dataset)")
    parser.add_argument("--window", type=float, default=60.0, help="seconds of 1x playback")
    parser.add_argument("--clients", type=int, default=2, help="websocket clients")
    parser.add_argument("--skip-replay", action="store_true", help="only the synthetic map")
    args = parser.parse_args()
    if not args.skip_replay:
        if args.bag is None:
            from cogmap_core.datasets.cache import default_dataset_path

            bag = default_dataset_path()
        else:
            bag = Path(args.bag)
        part1(bag, args.window, args.clients)
    part2(min(args.window, 20.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
