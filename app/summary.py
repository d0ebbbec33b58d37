"""What a session's report says (``summary.json``, ``sizes.csv``), for ``cogmap run`` and the page.

The headless run (:mod:`app.pipeline`) writes them into its report folder when the data ends; the
web app's export (:mod:`app.server.export`) makes the same files from the frames replayed so far.
Both call :func:`session_summary` and :func:`write_sizes_csv`, so the two always agree.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.datasets import BagReader
from cogmap_core.datasets.camera_common import CameraReader
from cogmap_core.evaluation import MapAccuracy, map_accuracy
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.parameter_table import PAPER_PARAMETERS
from cogmap_core.slam import (
    ALL_MODES,
    SlamSession,
    map_false_loop_edge_mask,
    map_rejected_loop_edges,
    optimisation_summary,
)
from cogmap_core.sources.detect import Source
from cogmap_core.sources.log_reader import LogReader

#: The order of the maps in every report (the session's: standard, scene integration, compact).
MAP_ORDER: tuple[MapMode, ...] = ALL_MODES


@dataclass(frozen=True, slots=True)
class FinalMap:
    """One map as the report sees it: copied once (a snapshot), with its accuracy.

    Attributes:
        cmap: the map itself (its counters, optimisations and size history).
        snapshot: a copy of its live vertices and edges.
        truth: the ground-truth pose at each live vertex's creation time (rows of
            ``snapshot``), or None without ground truth.
        accuracy: its ATE, layout fidelity (at the session's radius) and alignment to the
            truth, or None without ground truth.

    """

    cmap: CognitiveMap
    snapshot: MapSnapshot
    truth: NDArray[np.float64] | None
    accuracy: MapAccuracy | None


def final_maps(session: SlamSession) -> dict[MapMode, FinalMap]:
    """Every map of ``session`` copied once, with everything a report computes from it."""
    radius = session.evaluation.layout_radius
    log = session.log
    maps = {}
    for mode in MAP_ORDER:
        cmap = session.maps[mode]
        snapshot = cmap.snapshot()
        truth = log.truth_at(snapshot.vertex_time)  # None without ground truth
        accuracy = None
        if truth is not None:
            accuracy = map_accuracy(snapshot, truth, np.asarray(log.ground_truth), radius)
        maps[mode] = FinalMap(cmap, snapshot, truth, accuracy)
    return maps


def session_summary(
    session: SlamSession,
    dataset: str,
    first: float,
    last: float,
    wall: float,
    read_warnings: dict[str, Any],
    source: dict[str, Any] | None = None,
    maps: Mapping[MapMode, FinalMap] | None = None,
) -> dict[str, Any]:
    """The ``summary.json`` of a session: per map sizes, fidelity, accuracy, timings; links.

    Args:
        session: the session (its maps and event log).
        dataset: the input, as written into the summary.
        first: data time of the first frame processed (s).
        last: data time of the last frame processed (s).
        wall: wall time the processing took (s).
        read_warnings: the reader's non-zero problem counters.
        source: what the input is and how it was read (``format``, a log's settings and what
            became of its loop candidates).
        maps: the session's maps as :func:`final_maps` copied them (default: copied here).

    """
    judging = session.evaluation
    layout_radius = judging.layout_radius  # (:attr:`SlamSession.evaluation`)
    duration = max(last - first, 0.0)
    if maps is None:
        maps = final_maps(session)
    entries: dict[str, Any] = {}
    for mode in MAP_ORDER:
        final = maps[mode]
        cmap = final.cmap
        entry: dict[str, Any] = optimisation_summary(cmap)
        accuracy = final.accuracy
        ate = None if accuracy is None else accuracy.ate
        entry["ate_m"] = None if ate is None else round(ate, 6)
        fidelity = None if accuracy is None else accuracy.fidelity
        entry["edges_per_vertex"] = (
            round(cmap.num_edges / cmap.num_vertices, 4) if cmap.num_vertices else None
        )
        entry["completeness"] = None if fidelity is None else _rounded(fidelity.completeness)
        entry["correctness"] = None if fidelity is None else _rounded(fidelity.correctness)
        c = cmap.counters
        entry["proposed"] = c.proposed
        entry["declined"] = c.declined
        entry["integrated"] = c.integrated
        entry["split_again"] = c.split  # merged, then put back when their link was rejected
        entry["short_edges_removed"] = c.short_edges
        entry["duplicate_links"] = c.duplicate_links
        entry["refused_relocalisations"] = c.refused_relocalisations
        # loop-closure edges of the map made from a link the ground truth calls false (the
        # page's "false loop closures in the map"; None without ground truth)
        false_edges = map_false_loop_edge_mask(session.log, cmap, judging, final.snapshot)
        entry["false_loop_edges"] = (
            None if false_edges is None else int(np.count_nonzero(false_edges))
        )
        # the loop model's verdict at the final estimate, and (ground truth) how many were true
        rejected, rejected_true = map_rejected_loop_edges(
            session.log, cmap, false_edges=false_edges
        )
        entry["rejected_loop_edges"] = rejected
        entry["rejected_true_loop_edges"] = rejected_true
        entries[mode.value] = entry
    score = session.loop_closure_score()
    links = session.log.link_table()
    if score is None:
        loops: dict[str, Any] = {
            "total": len(links),
            "true": None,
            "false": None,
            "precision": None,
            "false_links": None,
        }
    else:
        assert score.position_error is not None and score.heading_error is not None
        heading = judging.loop_heading
        scores = session.log.link_scores
        loops = {
            "total": score.total,
            "true": score.true,
            "false": score.false,
            "precision": score.precision,
            "tolerance_m": judging.loop_distance,
            "tolerance_deg": None if heading is None else round(math.degrees(heading), 6),
            "false_links": [
                _false_link(session, links, scores, score, k) for k in score.false_indices
            ],
        }
    dead_reckoning = session.log.dead_reckoning_ate()
    p = session.params
    return {
        "dataset": dataset,
        "frames": session.log.frames,
        "data_duration_s": round(duration, 6),
        "wall_s": round(wall, 6),
        "realtime_factor": round(duration / wall, 3) if wall > 0 else None,
        "params": {name: getattr(p, name) for name in PAPER_PARAMETERS},
        "layout_radius_m": layout_radius,
        "dead_reckoning_ate_m": None if dead_reckoning is None else round(dead_reckoning, 6),
        "maps": entries,
        "loop_closures": loops,
        "read_warnings": read_warnings,
        "source": dict(source or {}),
    }


def _false_link(
    session: SlamSession,
    links: list[tuple[float, int, float]],
    scores: list[float | None],
    score: Any,
    k: int,
) -> dict[str, Any]:
    entry: dict[str, Any] = {
        "time": round(links[k][0], 6),
        "target": links[k][1],
        "position_error_m": round(float(score.position_error[k]), 4),
    }
    if session.evaluation.loop_heading is not None:
        entry["heading_error_deg"] = round(math.degrees(float(score.heading_error[k])), 2)
    link_score = scores[k]
    if link_score is not None:
        entry["score"] = round(link_score, 6)
    return entry


def source_description(reader: Source) -> dict[str, Any]:
    """What the input is and how it was read, for the report."""
    if isinstance(reader, LogReader | CameraReader):
        return reader.description()
    if isinstance(reader, BagReader) and reader.visual_odometry:
        return {"format": "bag", "odometry": "visual"}
    return {"format": "bag"}


def read_warnings(reader: Source) -> dict[str, Any]:
    """The reader's non-zero problem counters (``summary.json``'s ``read_warnings``)."""
    return {k: v for k, v in asdict(reader.counters).items() if k != "frames" and v}


def _rounded(value: float) -> float | None:
    return None if math.isnan(value) else round(value, 6)


def write_sizes_csv(maps: Mapping[MapMode, CognitiveMap], handle: TextIO) -> None:
    """Write ``sizes.csv``: time and each map's vertices/edges on the union of change times."""
    histories = {m: maps[m].size_history() for m in MAP_ORDER}
    times = np.unique(np.concatenate([h[0] for h in histories.values()]))
    writer = csv.writer(handle)
    header = ["time"]
    for m in MAP_ORDER:
        header += [f"{m.value}_vertices", f"{m.value}_edges"]
    writer.writerow(header)
    columns = []
    for m in MAP_ORDER:
        t, v, e = histories[m]
        idx = np.searchsorted(t, times, side="right") - 1
        columns.append(np.where(idx >= 0, v[np.maximum(idx, 0)], 0))
        columns.append(np.where(idx >= 0, e[np.maximum(idx, 0)], 0))
    for row in range(times.size):
        writer.writerow([f"{times[row]:.6f}"] + [int(c[row]) for c in columns])
