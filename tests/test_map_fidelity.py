"""The three maps on streams the front end really emitted (recorded from generated bags).

Each recording (``tests/data/*.events.npz``, made by ``tests/data/make_event_recordings.py``)
holds the events of a small generated bag and its ground truth per frame. The maps must keep the
layout -- completeness and correctness against the dense true path -- beat dead reckoning, and
the compact map must stay small.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from tests.conftest import DATA

RECORDINGS = ["figure_eight_3laps", "junction_dead_end_2laps"]


@pytest.fixture(scope="module", params=RECORDINGS)
def built(request):
    log = EventLog.from_recording(load_event_file(DATA / f"{request.param}.events.npz"))
    maps = {}
    for mode in MapMode:
        cmap = CognitiveMap(mode)
        cmap.apply_all(log.events)
        cmap.finish(log.frame_time[-1])
        maps[mode] = cmap
    return request.param, log, maps


def test_every_map_keeps_the_layout(built):
    name, log, maps = built
    for mode, cmap in maps.items():
        fidelity = log.layout_fidelity(cmap)
        floor = 0.99 if mode is MapMode.STANDARD else 0.98
        assert fidelity.completeness >= floor, (name, mode, fidelity)
        assert fidelity.correctness >= floor, (name, mode, fidelity)
        assert fidelity.edges_per_vertex <= 1.5, (name, mode, fidelity)


def test_the_single_figures_are_those_of_map_accuracy(built):
    # benchmarks take ATE and fidelity from one map_accuracy; the page and sweeps do too
    name, log, maps = built
    for mode, cmap in maps.items():
        accuracy = log.map_accuracy(cmap.snapshot())
        assert accuracy is not None, (name, mode)
        assert log.layout_fidelity(cmap) == accuracy.fidelity, (name, mode)
        assert log.map_ate(cmap) == accuracy.ate, (name, mode)


def test_every_map_beats_dead_reckoning(built):
    name, log, maps = built
    dead_reckoning = log.dead_reckoning_ate()
    standard = log.map_ate(maps[MapMode.STANDARD])
    for mode, cmap in maps.items():
        ate = log.map_ate(cmap)
        assert ate <= 0.5 * dead_reckoning, (name, mode, ate, dead_reckoning)
        assert ate <= 1.6 * standard, (name, mode, ate, standard)


def test_compact_map_is_small_and_scene_integration_removes_only_revisits(built):
    name, log, maps = built
    standard = maps[MapMode.STANDARD]
    integrated = maps[MapMode.SCENE_INTEGRATION]
    compact = maps[MapMode.COMPACT]
    assert compact.num_vertices <= 0.15 * standard.num_vertices
    assert integrated.num_vertices < standard.num_vertices
    # every vertex scene integration removed lies where the true path had already passed at
    # least integration_min_age (10 s) before it was made: a revisit, never a first visit
    snap = standard.snapshot()
    truth = log.truth_at(snap.vertex_time)
    path = np.asarray(log.ground_truth)[:, :2]
    frame_time = np.asarray(log.frame_time)
    removed = 0
    for k, v in enumerate(snap.vertex_ids.tolist()):
        if integrated.resolve(v)[0] == v:
            continue
        removed += 1
        earlier = path[frame_time <= snap.vertex_time[k] - 10.0]
        assert earlier.size, (name, v)
        gap, _ = cKDTree(earlier).query(truth[k, :2])
        assert gap <= 0.1, (name, v, gap)
    assert removed == standard.num_vertices - integrated.num_vertices


def test_loop_closures_are_judged_by_position_and_heading(built):
    name, log, _ = built
    score = log.loop_closure_score()
    assert score.precision >= 0.95
    loose = log.loop_closure_score(heading=4.0)  # heading ignored
    assert loose.true >= score.true
    assert len(score.false_indices) == score.false
    links = log.link_table()
    for k in score.false_indices:
        assert 0 <= k < len(links)
