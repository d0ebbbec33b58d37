"""The headless pipeline: an input through its front end into the three maps, and a report folder.

The input is a bag (camera frames through the RatSLAM front end) or a log of odometry and place
recognition (steps whose events are known, :mod:`cogmap_core.sources`); :func:`open_source` hides
the difference. ``HeadlessPipeline(...).run()`` reads as the list of steps it performs; the
result object holds everything written to the run folder.
"""

from __future__ import annotations

import json
import math
import time as wallclock
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.inputs import InputOptions
from app.report import ReportFolder
from app.report_figures import map_figure, save_figure, size_figure
from app.summary import (
    MAP_ORDER,
    FinalMap,
    final_maps,
    read_warnings,
    session_summary,
    source_description,
    write_sizes_csv,
)
from cogmap_core import __version__
from cogmap_core.cognitive_map import MapMode
from cogmap_core.datasets import BagReader, BagTopics
from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.evaluation import LAYOUT_RADIUS
from cogmap_core.event_file import save_event_file
from cogmap_core.fileio import check_output_file, output_error
from cogmap_core.frames import Frame
from cogmap_core.g2o import write_g2o
from cogmap_core.session_file import SessionMeta, resume_session, save_session
from cogmap_core.session_file import describe as session_description
from cogmap_core.slam import SlamSession, map_false_loop_edge_mask
from cogmap_core.sources.detect import (
    KINDS,
    Source,
    check_sessions_allowed,
    input_map_params,
    open_source,
    resolve_format,
)

#: Every file a report folder can hold (``--force`` replaces only these, see app/report.py).
REPORT_FILES: tuple[str, ...] = (
    "config.json",
    "summary.json",
    "sizes.csv",
    *(f"{m.value}.g2o" for m in MAP_ORDER),
    "trajectory_tum.txt",
    "groundtruth_tum.txt",
    "size.png",
    "size.svg",
    "map.png",
    "map.svg",
)
ProgressCallback = Callable[[int, int, float], None]


@dataclass(frozen=True, slots=True)
class RunOptions:
    """Everything that defines a headless run besides the input's path (a bag or a log).

    Attributes:
        input: how the input is read (:class:`~app.inputs.InputOptions`: its kind, the front
            end -- None: iRat defaults + the bag's profile; unused for logs --, a bag's topics
            and JPEG scale, how to read a log, a camera's motion).
        force: overwrite a non-empty report folder and an existing ``save_session`` file.
        on_clock_jump: a bag's clock jumping back: ``drop`` or ``stop`` (bags only).
        until_error: a bag corrupt part-way: map what comes before the damage (bags only).
        resume: continue the session saved in this file (its front end, maps and data time);
            the bag's frames follow the session's as if the bags were one (bags only).
        param_changes: map parameters that replace the input's defaults
            (:func:`~cogmap_core.sources.detect.input_map_params`) for a new session, or
            with ``resume`` the session's own (its maps are then rebuilt from its events).
        save_session: write the session to this file at the end of the data (before the final
            optimisation, so that a resumed run continues exactly where this one stopped; bags
            only).
        save_events: write the map events of the run (the front end's, or a log's) to this
            event file at the end of the data, as ``cogmap sweep`` records and reads them.

    """

    input: InputOptions = field(default_factory=InputOptions)
    force: bool = False
    on_clock_jump: str = "drop"  # or "stop": see cogmap_core.datasets.rosbag_reader
    until_error: bool = False  # a bag corrupt part-way: map what comes before the damage
    resume: Path | None = None
    param_changes: Mapping[str, float] = field(default_factory=dict)
    save_session: Path | None = None
    save_events: Path | None = None


@dataclass
class RunResult:
    """The report of one run (also written as ``summary.json``)."""

    summary: dict[str, Any]
    out_dir: Path
    files: list[Path]
    warnings: list[str] = field(default_factory=list)  # the reader's, one line each
    session_notes: list[str] = field(default_factory=list)

    def table(self) -> str:
        """A compact one-line-per-map summary table."""
        radius = self.summary.get("layout_radius_m", LAYOUT_RADIUS)
        lines = [
            f"{'map':18} {'vertices':>8} {'edges':>7} {'E/V':>5} {'loops':>6} {'clusters':>8} "
            f"{'optims':>6} {'opt s':>6} {'ATE m':>7} {'compl':>6} {'corr':>6} "
            f"{'rejected (true)':>15}"
        ]

        def fmt(value: float | None, spec: str) -> str:
            return "-" if value is None else format(value, spec)

        for name, m in self.summary["maps"].items():
            lines.append(
                f"{name:18} {m['vertices']:8d} {m['edges']:7d} "
                f"{fmt(m['edges_per_vertex'], '5.2f')} "
                f"{m['loop_edges']:6d} {m['clusters']:8d} {m['optimizations']:6d} "
                f"{m['optimize_wall_s']:6.2f} {fmt(m['ate_m'], '7.3f'):>7} "
                f"{fmt(m['completeness'], '6.3f'):>6} {fmt(m['correctness'], '6.3f'):>6} "
                f"{_rejected_cell(m):>15}"
            )
        s = self.summary
        lc = s["loop_closures"]
        precision = "-" if lc["precision"] is None else f"{lc['precision']:.3f}"
        dead_reckoning = s.get("dead_reckoning_ate_m")
        lines.append(
            f"compl/corr: share of the true path within {radius * 100:g} cm of the map / of the "
            f"map within {radius * 100:g} cm of the true path; dead-reckoning ATE "
            f"{fmt(dead_reckoning, '.3f')} m"
        )
        judged = "position only" if lc.get("tolerance_deg") is None else "position and heading"
        lines.append(
            f"{s['frames']} frames, {s['data_duration_s']:.1f} s of data in {s['wall_s']:.1f} s "
            f"({s['realtime_factor']:.1f}x real time); loop closures {lc['total']} "
            f"(precision {precision}, {judged})"
        )
        return "\n".join(lines)


def _rejected_cell(entry: dict[str, Any]) -> str:
    """``N (T)``: loop-closure edges the loop model rejected (of them true), or ``N``."""
    rejected, true = entry.get("rejected_loop_edges"), entry.get("rejected_true_loop_edges")
    if rejected is None:
        return "-"
    return f"{rejected}" if true is None else f"{rejected} ({true})"


def _figure(value: float | None) -> str:
    """A figure of the report to three decimals, ``-`` where there is none.

    A map of one vertex has no ATE (nothing to align), one that covers none of the true path no
    correctness: a map too small to measure is still reported.
    """
    return "-" if value is None else f"{value:.3f}"


class HeadlessPipeline:
    """Process a whole input (bag or log) once and write the report folder.

    The report is staged and moved into place only when complete (:class:`app.report.ReportFolder`):
    an error, a full disk or Ctrl-C at any point leaves ``out_dir`` as it was.
    """

    def __init__(
        self,
        bag: Path,
        out_dir: Path,
        options: RunOptions | None = None,
        progress: ProgressCallback | None = None,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        """Set up a run of ``bag`` (a bag or a log) into ``out_dir``.

        ``announce`` is told when writing starts.

        Raises:
            ParameterError: a session (``resume``, ``save_session``) asked of a log.

        """
        self.bag = Path(bag)
        self.out_dir = Path(out_dir)
        self.options = options or RunOptions()
        self.progress = progress
        self.announce = announce
        self.format = resolve_format(self.bag, self.options.input.format)
        self.kind = KINDS[self.format]
        self.frontend = self.options.input.frontend_for(self.bag) if self.kind.has_camera else None
        self.files: list[Path] = []
        self.session_notes: list[str] = []
        options = self.options
        if options.resume is not None or options.save_session is not None:
            flag = "--resume" if options.resume is not None else "--save-session"
            check_sessions_allowed(self.format, self.bag, flag, f"run it whole, without {flag}")
        if options.save_session is not None:
            check_output_file(options.save_session, "--save-session", options.force)
        if options.save_events is not None:
            check_output_file(options.save_events, "--save-events", options.force)
        self.meta: SessionMeta | None = None
        self.session: SlamSession  # set by run(), once the output folder is checked

    def _start_session(self, reader: Source) -> SlamSession:
        """A new session, or the one ``resume`` names (loaded after the output is checked)."""
        changes = self.options.param_changes
        if self.options.resume is None:
            params = input_map_params(self.kind, reader).with_changes(**changes)
            return SlamSession(params, self.frontend, evaluation=self.kind.evaluation)
        path = self.options.resume
        started = wallclock.perf_counter()
        session, meta = resume_session(path, self.frontend, self.options.input.image_scale, changes)
        self.meta = meta
        self.session_notes.append(
            f"resumed {path} in {wallclock.perf_counter() - started:.2f} s: "
            f"{session_description(meta, session)}"
        )
        return session

    def run(self) -> RunResult:
        """Open the input, check the output, process every frame, evaluate, write the report."""
        with (
            self._open_source() as reader,
            ReportFolder(self.out_dir, REPORT_FILES, self.options.force) as report,
        ):
            self.session = self._start_session(reader)
            offset = 0.0
            if isinstance(reader, BagReader):  # a bag: what a session needs to know of it
                end = self.session.log.end_time
                if self.meta is None:
                    self.meta = SessionMeta(
                        epoch=reader.start_stamp, image_scale=self.options.input.image_scale
                    )
                else:
                    offset = self.meta.resume_offset(reader.start_stamp, end)
            started = wallclock.perf_counter()
            frames_before = self.session.log.frames
            first, last = self._process_frames(reader, offset)
            if self.meta is not None:
                self.meta.bags.append(
                    {
                        "bag": str(self.bag),
                        "offset": offset,
                        "frames": self.session.log.frames - frames_before,
                        "first": first,
                        "last": last,
                    }
                )
            if self.options.save_session is not None:
                self._save_session(self.options.save_session)
            self.session.finish()
            wall = wallclock.perf_counter() - started
            if self.options.save_events is not None:
                self._save_events(self.options.save_events)
            maps = final_maps(self.session)
            summary = self._summary(reader, first, last, wall, maps)
            self._announce(f"writing the report to {report.out_dir}")
            with report.writing():
                self._write_config(report)
                self._write_summary(report, summary)
                self._write_sizes(report)
                self._write_maps(report)
                self._write_trajectories(report, maps[MapMode.STANDARD])
                self._write_figures(report, last, summary, maps)
            self.files = report.commit()
        return RunResult(
            summary, report.out_dir, list(self.files), reader.warnings, list(self.session_notes)
        )

    # ------------------------------------------------------------------ steps
    def _announce(self, message: str) -> None:
        if self.announce is not None:
            self.announce(message)

    def _open_source(self) -> Source:
        o = self.options
        return open_source(
            self.bag,
            self.format,
            topics=o.input.topics,
            image_scale=o.input.image_scale,
            log=o.input.log,
            on_clock_jump=o.on_clock_jump,
            on_corrupt="stop" if o.until_error else "error",
            camera=replace(o.input.camera, frontend=self.frontend),
        )

    def _check_image_size(self, image: np.ndarray) -> None:
        """Refuse camera images too small for the view template (they would be magnified)."""
        assert self.frontend is not None
        min_w, min_h = self.frontend.minimum_image_size()
        height, width = image.shape[:2]
        if width < min_w or height < min_h:
            scale = self.options.input.image_scale
            need_w, need_h = self.frontend.minimum_image_size(scale)
            cfg = self.frontend
            raise InputFileError(
                f"{self.bag}: camera images of about {width * scale}x{height * scale} px are too "
                f"small for the {cfg.template_x_size}x{cfg.template_y_size} view template; "
                f"use a camera topic with images of at least {need_w}x{need_h} px"
            )

    def _process_frames(self, reader: Source, offset: float = 0.0) -> tuple[float, float]:
        """Every frame (or log step) through the session, placed at ``offset`` + its time."""
        first = last = math.nan
        total = reader.info.frame_count
        for frame in reader.frames():
            if offset:
                frame = replace(frame, time=frame.time + offset)
            if math.isnan(first):
                if isinstance(frame, Frame):
                    self._check_image_size(frame.image)
                first = frame.time
            last = frame.time
            self.session.process(frame)
            if self.progress is not None:
                self.progress(frame.index + 1, total, frame.time)
        if math.isnan(first):
            what = "decodable camera frame" if self.kind.has_camera else "step"
            raise InputFileError(f"{self.bag}: no {what}; nothing to map")
        return first, last

    def _save_session(self, path: Path) -> None:
        assert self.meta is not None
        started = wallclock.perf_counter()
        try:
            save_session(path, self.session, self.meta)
        except OSError as exc:  # the disk filled up or went read-only during the run
            raise output_error(path, exc) from None
        self.session_notes.append(
            f"session saved to {path} ({path.stat().st_size / 1e6:.1f} MB) in "
            f"{wallclock.perf_counter() - started:.2f} s: "
            f"{session_description(self.meta, self.session)}"
        )

    def _save_events(self, path: Path) -> None:
        """Write the session's events with their frames and ground truth as an event file."""
        frontend = {} if self.frontend is None else self.frontend.to_dict()
        recording = self.session.log.recording(str(self.bag), frontend)
        recording.meta["recorded_by"] = f"cogmap {__version__} run"
        recording.meta["input_format"] = self.format  # a sweep takes a bag's events only
        if self.frontend is not None:
            recording.meta["topics"] = asdict(self.options.input.topics or BagTopics())
            recording.meta["image_scale"] = self.options.input.image_scale
        try:
            save_event_file(path, recording)
        except OSError as exc:  # the disk filled up or went read-only during the run
            raise output_error(path, exc) from None
        self.session_notes.append(
            f"events saved to {path}: {len(recording.events)} events of {recording.frames} frames"
        )

    def _summary(
        self,
        reader: Source,
        first: float,
        last: float,
        wall: float,
        maps: Mapping[MapMode, FinalMap],
    ) -> dict[str, Any]:
        return session_summary(
            self.session,
            str(self.bag),
            first,
            last,
            wall,
            read_warnings(reader),
            source=source_description(reader),
            maps=maps,
        )

    @staticmethod
    def _write_json(report: ReportFolder, name: str, payload: dict[str, Any]) -> None:
        report.write_text(name, json.dumps(payload, indent=2) + "\n")

    def _write_config(self, report: ReportFolder) -> None:
        config: dict[str, Any] = {"dataset": str(self.bag), "format": self.format}
        config["map"] = self.session.params.to_dict()  # a resumed session's own
        if self.frontend is not None:
            config["image_scale"] = self.options.input.image_scale
            config["frontend"] = self.frontend.to_dict()
            config["topics"] = asdict(self.options.input.topics or BagTopics())
        else:
            log = self.options.input.log
            config["frontend"] = log.config.to_dict()
            config["loops"] = None if log.loops is None else str(log.loops)
            config["ground_truth"] = None if log.ground_truth is None else str(log.ground_truth)
            config["use_ground_truth"] = log.use_ground_truth
        self._write_json(report, "config.json", config)

    def _write_summary(self, report: ReportFolder, summary: dict[str, Any]) -> None:
        self._write_json(report, "summary.json", summary)

    def _write_sizes(self, report: ReportFolder) -> None:
        """sizes.csv: time and the vertices/edges of each map, on the union of change times."""
        with report.open("sizes.csv", newline="") as handle:
            write_sizes_csv(self.session.maps.maps, handle)

    def _write_maps(self, report: ReportFolder) -> None:
        for mode in MAP_ORDER:
            write_g2o(self.session.maps[mode].to_pose_graph(), report.path(f"{mode.value}.g2o"))

    def _write_trajectories(self, report: ReportFolder, standard: FinalMap) -> None:
        """TUM files for evo: the standard map's vertices, and the ground truth when known."""
        snap = standard.snapshot
        order = np.argsort(snap.vertex_time, kind="stable")
        times = snap.vertex_time[order]
        self._write_tum(report, "trajectory_tum.txt", times, snap.poses[order])
        if standard.truth is not None:
            self._write_tum(report, "groundtruth_tum.txt", times, standard.truth[order])

    @staticmethod
    def _write_tum(report: ReportFolder, name: str, times: np.ndarray, poses: np.ndarray) -> None:
        with report.open(name) as handle:
            handle.write("# timestamp tx ty tz qx qy qz qw\n")
            for t, (x, y, th) in zip(times.tolist(), poses.tolist(), strict=True):
                handle.write(
                    f"{t:.6f} {x:.6f} {y:.6f} 0 0 0 {math.sin(th / 2):.9f} {math.cos(th / 2):.9f}\n"
                )

    def _write_figures(
        self,
        report: ReportFolder,
        end_time: float,
        summary: dict[str, Any],
        maps: Mapping[MapMode, FinalMap],
    ) -> None:
        histories = {m: self.session.maps[m].size_history() for m in MAP_ORDER}
        png = report.path("size.png")
        report.path("size.svg")  # (written beside the PNG)
        save_figure(size_figure(histories, end_time), png)
        snaps = {m: maps[m].snapshot for m in MAP_ORDER}
        aligned: dict[MapMode, np.ndarray] = {}
        false: dict[MapMode, np.ndarray] = {}
        truth_path = None
        log = self.session.log
        if log.has_ground_truth():
            truth_path = np.asarray(log.ground_truth)
            judging = self.session.evaluation
            for mode in MAP_ORDER:
                accuracy = maps[mode].accuracy
                snap = snaps[mode]
                if accuracy is not None and accuracy.alignment is not None:
                    poses = snap.poses.copy()
                    poses[:, :2] = accuracy.alignment.apply(snap.poses[:, :2])
                    aligned[mode] = poses
                mask = map_false_loop_edge_mask(log, maps[mode].cmap, judging, snap)
                if mask is not None:
                    false[mode] = mask
        notes = {}
        for mode in MAP_ORDER:
            entry = summary["maps"][mode.value]
            if entry.get("completeness") is not None:  # (a figure may be None: "-")
                notes[mode] = (
                    f"ATE {_figure(entry['ate_m'])} m\ncompleteness "
                    f"{_figure(entry['completeness'])}, correctness {_figure(entry['correctness'])}"
                )
        png = report.path("map.png")
        report.path("map.svg")
        save_figure(map_figure(truth_path, snaps, aligned, notes, false), png)


def run_headless(
    bag: Path,
    out_dir: Path,
    options: RunOptions,
    progress: ProgressCallback | None = None,
    announce: Callable[[str], None] | None = None,
) -> RunResult:
    """Library entry of ``cogmap run``: process ``bag`` (or a log) into the report ``out_dir``.

    ``announce`` receives one-line notes of what is happening (e.g. that writing has started).
    """
    try:
        return HeadlessPipeline(bag, out_dir, options, progress, announce).run()
    except CogmapError:
        raise
    except MemoryError:
        raise CogmapError("out of memory while processing the input") from None
