"""Long-term mapping: one pass over a long generated bag, every cost and size printed per lap.

The paper's claim is long-term mapping: "the size of the map does not grow unless the unknown
environment is explored". This runs the whole pipeline once over a long bag (by default 60 laps of
the default layout: ``cogmap make-maze BAG --laps 60``) -- reading and JPEG decoding, the front
end, the event log, the three maps with their optimisations -- and prints per lap:

- vertices and edges of each map, view templates;
- ms per frame of reading, of the front end, of the event log and of each map (including its
  optimisations, whose share is printed too);
- layout completeness / correctness of the compact map at 8 cm (evaluation, not timed);
- the process's resident memory;

then the totals, the size change of each map over laps 3-N (raw and with ground first explored in
those laps set apart) with its fidelity and ATE, each map's optimiser pose blocks over laps 3-N --
and the scene-integration map rebuilt with the paper's merge (``integration_keeps_evidence`` 0)
beside, not timed --, the time to save the whole session and to load it again, and the targets.
It writes ``long_term.png`` (and ``long_term.svg``): sizes per map over time (left) and per-lap
cost per stage (right).

Targets (issue "Long-term mapping", 60 laps): compact vertices change laps 3-60 within +-3 % and
completeness / correctness >= 0.98 at lap 60; (issue "Compaction that keeps the evidence") compact
ATE <= 1.1 x the standard map's, the compact map's optimiser pose blocks (the vertices of its
latest batch optimisation, printed per map) <= 0.2 x the standard map's at lap 60 and within
+-5 % of lap 3's at every lap from 3 to 60; front end ms per frame lap 60 <= 1.3 x lap 6's;
compact map ms per frame lap 60 <= 1.3 x lap 6's; whole run >= 50x real time; peak RSS <= 1 GB;
saving and resuming the session <= 5 s each.

Usage: ``python benchmarks/long_term.py BAG [--laps 60] [--layout irat_australia] [--seed 1]
[--out DIR]`` (the lap times come from the generator's plan of that layout, laps and seed).
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.report_figures import long_term_figure, save_figure
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.datasets import open_bag
from cogmap_core.datasets.generator import MazeConfig, plan_dataset
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.evaluation import LAYOUT_RADIUS, LayoutFidelity, SizeChange
from cogmap_core.map_modes import ALL_MODES
from cogmap_core.session_file import SessionMeta, load_session, save_session
from cogmap_core.slam import SlamSession

MODES = ALL_MODES
SHORT = {MapMode.STANDARD: "std", MapMode.SCENE_INTEGRATION: "si", MapMode.COMPACT: "cmp"}
STAGES = ("read", "frontend", "log", *(m.value for m in MODES))


def rss_mb() -> float:
    """Current resident set size of this process (MB)."""
    try:
        with open("/proc/self/status") as handle:
            for line in handle:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return peak_rss_mb()


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass
class Lap:
    """What one lap cost and left behind."""

    lap: int
    frames: int
    data_s: float
    seconds: dict[str, float]
    optimise_s: dict[MapMode, float]
    vertices: dict[MapMode, int]
    edges: dict[MapMode, int]
    #: pose blocks of each map's latest optimisation so far (0: none yet)
    pose_blocks: dict[MapMode, int]
    templates: int
    completeness: float
    correctness: float
    rss: float

    def ms(self, stage: str) -> float:
        """Milliseconds per frame of a stage in this lap."""
        return 1e3 * self.seconds[stage] / max(self.frames, 1)


@dataclass
class Run:
    """A timed pass over the bag."""

    session: SlamSession
    laps: list[Lap] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    finish_s: float = 0.0
    save_s: float = math.nan
    load_s: float = math.nan
    session_bytes: int = 0
    first: float = math.nan
    last: float = math.nan


def timed_pass(bag: Path, lap_times: tuple[float, ...]) -> Run:
    """Process every frame (the steps of ``SlamSession.process``, timed one by one)."""
    session = SlamSession(frontend_config=frontend_config_for(bag))
    run = Run(session)
    lap_seconds = dict.fromkeys(STAGES, 0.0)
    lap_frames = 0
    lap_start = 0.0
    opt_before = dict.fromkeys(MODES, 0.0)
    maps = [(mode.value, session.maps[mode]) for mode in MODES]
    clock = time.perf_counter
    laps = len(lap_times) - 1
    with open_bag(bag, image_scale=1) as reader:  # as cogmap run
        frames = reader.frames()
        epoch = reader.start_stamp
        while True:
            t0 = clock()
            frame = next(frames, None)
            t1 = clock()
            lap_seconds["read"] += t1 - t0
            boundary = len(run.laps) + 1
            if frame is None or (boundary < laps and frame.time >= lap_times[boundary]):
                _close_lap(run, lap_seconds, lap_frames, lap_start, opt_before, frame)
                lap_seconds = dict.fromkeys(STAGES, 0.0)
                lap_frames = 0
                lap_start = frame.time if frame is not None else lap_start
                if frame is None:
                    break
            if math.isnan(run.first):
                run.first = frame.time
            run.last = frame.time
            t0 = clock()
            events = session.frontend.process(frame)
            t1 = clock()
            truth = frame.ground_truth
            session.log.append_frame(
                events,
                frame.time,
                None if truth is None else (float(truth[0]), float(truth[1]), float(truth[2])),
            )
            t2 = clock()
            lap_seconds["frontend"] += t1 - t0
            lap_seconds["log"] += t2 - t1
            for name, cmap in maps:
                t0 = clock()
                for event in events:
                    cmap.apply(event)
                lap_seconds[name] += clock() - t0
            lap_frames += 1
    # the session as cogmap run --save-session saves it: before the final optimisation
    with tempfile.TemporaryDirectory(prefix="cogmap-long-term-") as tmp:
        path = Path(tmp) / "session.npz"
        t0 = clock()
        save_session(path, session, SessionMeta(epoch=epoch, bags=[{"bag": str(bag)}]))
        run.save_s = clock() - t0
        run.session_bytes = path.stat().st_size
        t0 = clock()
        load_session(path)
        run.load_s = clock() - t0
    t0 = clock()
    session.finish()
    run.finish_s = clock() - t0
    return run


def _close_lap(
    run: Run,
    seconds: dict[str, float],
    frames: int,
    start: float,
    opt_before: dict[MapMode, float],
    frame: object,
) -> None:
    session = run.session
    for stage, value in seconds.items():
        run.seconds[stage] += value
    optimise = {}
    for mode in MODES:
        total = sum(o.wall_s for o in session.maps[mode].optimizations)
        optimise[mode] = total - opt_before[mode]
        opt_before[mode] = total
    compact = session.maps[MapMode.COMPACT]
    fidelity = session.layout_fidelity(compact, LAYOUT_RADIUS)
    end = run.last
    lap = Lap(
        lap=len(run.laps) + 1,
        frames=frames,
        data_s=end - start,
        seconds=dict(seconds),
        optimise_s=optimise,
        vertices={m: session.maps[m].num_vertices for m in MODES},
        edges={m: session.maps[m].num_edges for m in MODES},
        pose_blocks={m: _pose_blocks(session.maps[m]) for m in MODES},
        templates=session.frontend.template_count,
        completeness=math.nan if fidelity is None else fidelity.completeness,
        correctness=math.nan if fidelity is None else fidelity.correctness,
        rss=rss_mb(),
    )
    run.laps.append(lap)
    print(_lap_line(lap), flush=True)


def _pose_blocks(cmap: CognitiveMap) -> int:
    """Pose blocks (vertices) in a map's latest batch optimisation (0 before the first)."""
    return cmap.optimizations[-1].vertices if cmap.optimizations else 0


def _header() -> str:
    sizes = " ".join(f"{SHORT[m] + ' V/E':>11}" for m in MODES)
    costs = " ".join(f"{SHORT[m] + ' (opt)':>13}" for m in MODES)
    return (
        f"{'lap':>3} {'frames':>6} {sizes} {'tmpl':>5} | ms/frame: {'read':>5} {'front':>5} "
        f"{'log':>5} {costs} | {'compl':>6} {'corr':>6} {'RSS MB':>7}"
    )


def _lap_line(lap: Lap) -> str:
    sizes = " ".join(f"{lap.vertices[m]:>5d}/{lap.edges[m]:<5d}" for m in MODES)
    costs = " ".join(
        f"{lap.ms(m.value):6.3f} ({1e3 * lap.optimise_s[m] / max(lap.frames, 1):5.3f})"
        for m in MODES
    )
    return (
        f"{lap.lap:3d} {lap.frames:6d} {sizes} {lap.templates:5d} | ms/frame: "
        f"{lap.ms('read'):5.3f} {lap.ms('frontend'):5.3f} {lap.ms('log'):5.3f} {costs} | "
        f"{lap.completeness:6.3f} {lap.correctness:6.3f} {lap.rss:7.0f}"
    )


def figure(run: Run, lap_times: tuple[float, ...]) -> Any:
    """Sizes per map over time (left) and per-lap ms per frame of each stage (right)."""
    histories = {m: run.session.maps[m].size_history() for m in MODES}
    return long_term_figure(
        histories,
        run.last,
        [lap.lap for lap in run.laps],
        {stage: [lap.ms(stage) for lap in run.laps] for stage in STAGES},
        f"{len(lap_times) - 1} laps, {run.session.log.frames} frames, "
        f"{run.last / 3600:.2f} h of data",
    )


def main() -> int:
    """Run the benchmark; exit code 0 when every target is met."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag", type=Path, help="a generated bag (cogmap make-maze BAG --laps N)")
    parser.add_argument("--laps", type=int, default=60, help="laps the bag was made with")
    parser.add_argument("--layout", default="irat_australia", help="its layout")
    parser.add_argument("--seed", type=int, default=1, help="its seed")
    parser.add_argument("--out", type=Path, default=Path("."), help="folder for long_term.png")
    args = parser.parse_args()
    plan = plan_dataset(MazeConfig(layout=args.layout, laps=args.laps, seed=args.seed))
    lap_times = plan.trajectory.lap_times
    with open_bag(args.bag) as reader:
        if reader.info.frame_count != plan.frame_times.size:
            print(
                f"{args.bag} has {reader.info.frame_count} frames, the plan of {args.layout} "
                f"with {args.laps} laps and seed {args.seed} has {plan.frame_times.size}; give "
                "the settings the bag was made with",
                file=sys.stderr,
            )
            return 2
    print(f"{args.bag}: {args.laps} laps, {plan.frame_times.size} frames, {lap_times[-1]:.0f} s")
    print(_header())
    started = time.perf_counter()
    run = timed_pass(args.bag, lap_times)
    wall_all = time.perf_counter() - started
    log = run.session.log
    duration = run.last - run.first
    pipeline_s = sum(run.seconds.values()) + run.finish_s
    print(
        f"total {log.frames} frames, {duration:.0f} s of data: "
        + ", ".join(f"{s} {run.seconds[s]:.1f} s" for s in STAGES)
        + f", final optimisation {run.finish_s:.2f} s; pipeline {pipeline_s:.1f} s "
        f"({duration / pipeline_s:.1f}x real time; with evaluation and session timing "
        f"{wall_all:.0f} s); peak RSS {peak_rss_mb():.0f} MB"
    )
    laps = len(lap_times) - 1
    first_lap = min(3, laps)
    dead_reckoning = log.dead_reckoning_ate()
    if dead_reckoning is not None:
        print(f"dead-reckoning ATE {dead_reckoning:.3f} m (the baseline of the maps' ATE)")

    def describe(label: str, cmap: CognitiveMap) -> tuple[SizeChange, LayoutFidelity, float | None]:
        """Print one map's size change, fidelity and ATE; return them."""
        change = log.size_change(cmap, lap_times[first_lap], lap_times[laps], LAYOUT_RADIUS)
        accuracy = log.map_accuracy(cmap.snapshot(), LAYOUT_RADIUS)
        assert change is not None and accuracy is not None
        fidelity, ate = accuracy.fidelity, accuracy.ate
        optimise_s = sum(o.wall_s for o in cmap.optimizations)
        print(
            f"  {label:18} V {cmap.num_vertices:5d} E {cmap.num_edges:5d}; end of lap "
            f"{first_lap} to {laps}: {change.start_vertices} -> {change.end_vertices} vertices, "
            f"{change.change:+.1%} ({change.change_without_exploration:+.1%} without the "
            f"{change.exploration_vertices} made on ground first explored then); completeness "
            f"{fidelity.completeness:.4f}, correctness {fidelity.correctness:.4f}"
            + ("" if ate is None else f", ATE {ate:.4f} m")
            + f"; {len(cmap.optimizations)} optimisations, {optimise_s:.1f} s"
        )
        return change, fidelity, ate

    changes = {}
    fidelities = {}
    ates: dict[MapMode, float | None] = {}
    for mode in MODES:
        changes[mode], fidelities[mode], ates[mode] = describe(mode.value, run.session.maps[mode])
    merged = MapMode.SCENE_INTEGRATION
    params = run.session.maps[merged].params
    if params.integration_keeps_evidence >= 0.5:  # the paper's merge, beside (not timed)
        paper = params.with_changes(integration_keeps_evidence=0.0)
        describe("SI, paper's merge", run.session.rebuild(paper, modes=(merged,))[merged])
    print(
        f"session: saved in {run.save_s:.2f} s, loaded in {run.load_s:.2f} s, "
        f"{run.session_bytes / 1e6:.1f} MB ({run.session.frontend.template_count} templates, "
        f"{log.event_count} events)"
    )
    blocks = {m: [lap.pose_blocks[m] for lap in run.laps[first_lap - 1 :]] for m in MODES}
    for mode in MODES:
        series = blocks[mode]
        share = series[-1] / max(blocks[MapMode.STANDARD][-1], 1)
        print(
            f"  {mode.value:18} optimiser pose blocks: lap {first_lap} {series[0]}, lap {laps} "
            f"{series[-1]} ({series[-1] / max(series[0], 1) - 1:+.1%}), laps {first_lap}-{laps} "
            f"{min(series)}-{max(series)}; lap {laps} {share:.3f} x the standard map's"
        )
    for k in sorted({6, (laps + 1) // 2, 30, laps} & set(range(1, laps + 1))):
        print("  " + _lap_line(run.laps[k - 1]))
    args.out.mkdir(parents=True, exist_ok=True)
    written = save_figure(figure(run, lap_times), args.out / "long_term.png")
    print("wrote " + ", ".join(str(path) for path in written))

    fidelity = fidelities[MapMode.COMPACT]
    ref = run.laps[min(6, laps) - 1]
    last = run.laps[-1]
    fe_ratio = last.ms("frontend") / ref.ms("frontend")
    cmp_ratio = last.ms("compact") / ref.ms("compact")
    realtime = duration / pipeline_s
    peak = peak_rss_mb()
    change = changes[MapMode.COMPACT]
    compact_blocks, standard_blocks = blocks[MapMode.COMPACT], blocks[MapMode.STANDARD]
    blocks_ratio = compact_blocks[-1] / max(standard_blocks[-1], 1)
    blocks_spread = max(abs(b / max(compact_blocks[0], 1) - 1) for b in compact_blocks)
    ate_std, ate_cmp = ates[MapMode.STANDARD], ates[MapMode.COMPACT]
    ate_ratio = math.inf if not ate_std or ate_cmp is None else ate_cmp / ate_std
    checks = [
        (
            f"compact vertices change laps {first_lap}-{laps} within +-3 % (raw "
            f"{change.change:+.1%}, without exploration {change.change_without_exploration:+.1%})",
            abs(change.change) <= 0.03,
        ),
        (
            f"compact completeness, correctness >= 0.98 at lap {laps} "
            f"({fidelity.completeness:.4f}, {fidelity.correctness:.4f})",
            min(fidelity.completeness, fidelity.correctness) >= 0.98,
        ),
        (f"compact ATE <= 1.1 x standard ({ate_ratio:.2f} x)", ate_ratio <= 1.1),
        (
            f"compact optimiser pose blocks lap {laps} <= 0.2 x standard's ({blocks_ratio:.3f})",
            blocks_ratio <= 0.2,
        ),
        (
            f"compact optimiser pose blocks flat laps {first_lap}-{laps}: every lap within +-5 % "
            f"of lap {first_lap}'s (largest change {blocks_spread:+.1%})",
            blocks_spread <= 0.05,
        ),
        (f"front end ms/frame lap {laps} <= 1.3 x lap {ref.lap} ({fe_ratio:.2f})", fe_ratio <= 1.3),
        (f"compact ms/frame lap {laps} <= 1.3 x lap {ref.lap} ({cmp_ratio:.2f})", cmp_ratio <= 1.3),
        (f"whole run >= 50x real time ({realtime:.1f}x)", realtime >= 50),
        (f"peak RSS <= 1 GB ({peak:.0f} MB)", peak <= 1024),
        (f"session save <= 5 s ({run.save_s:.2f} s)", run.save_s <= 5),
        (f"session load <= 5 s ({run.load_s:.2f} s)", run.load_s <= 5),
    ]
    for label, ok in checks:
        print(f"  {'OK    ' if ok else 'MISSED'} {label}")
    print(
        f"long-term: compact change laps {first_lap}-{laps} {change.change:+.1%}, front end "
        f"lap{laps}/lap{ref.lap} {fe_ratio:.2f}, realtime {realtime:.1f}x, peak RSS {peak:.0f} MB"
    )
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
