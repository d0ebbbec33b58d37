"""Issue 25: figures of the page that were wrong or contradicted each other, on real servers.

False loop closures in the map (one definition, the same in ``summary.json``), the false links
counted up to where the replay is, and counters that say where the links went.
"""

from __future__ import annotations

import bisect
import json
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.server.export import summary_dict, summary_inputs
from cogmap_core.cognitive_map import MapMode
from cogmap_core.evaluation import loop_edge_links
from cogmap_core.slam import SlamSession, link_resolution, map_false_loop_edges
from cogmap_core.sources.detect import open_source
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests import test_server_support as support
from tests.test_server_support import counter, running_app, until, wait

false_log = support.false_log
short_bag = support.short_bag
reference = support.reference


@pytest.fixture(scope="module")
def log_reference(false_log: Path) -> SlamSession:
    reader = open_source(false_log)
    session = SlamSession(LOG_MAP_PARAMS, evaluation=reader.evaluation)
    session.run(reader.frames())
    return session


def _links(session: SlamSession) -> tuple[np.ndarray, np.ndarray]:
    table = session.log.link_table()
    return np.array([t for t, _, _ in table]), np.array([g for _, g, _ in table], dtype=np.int64)


def test_every_loop_edge_of_a_map_is_traced_to_the_link_that_made_it(
    log_reference: SlamSession, reference: SlamSession
) -> None:
    for session in (log_reference, reference):
        times, targets = _links(session)
        for mode in MapMode:
            cmap = session.maps[mode]
            snap = cmap.snapshot()
            alias, refused = link_resolution(cmap)
            made = loop_edge_links(times, targets, snap, alias, refused)
            loops = snap.edge_kind == 1
            assert (made[~loops] == -1).all()
            assert (made[loops] >= 0).all()  # every loop edge has its link
            assert len(set(made[loops].tolist())) == int(loops.sum())  # one link per edge
            k = made[loops]
            assert (times[k] == snap.edge_time[loops]).all()
            assert (alias[targets[k]] == snap.edge_to[loops]).all()
            c = cmap.counters
            refused_links = sum((t, g) in refused for t, g in zip(times, targets, strict=True))
            assert c.links == times.size
            # the links a map did not refuse and that joined no joined pair made its edges
            made_ever = c.links - refused_links - c.duplicate_links
            assert made_ever >= cmap.num_loop_edges
            if mode is MapMode.STANDARD:  # (it never merges: every edge it made is there)
                assert made_ever == cmap.num_loop_edges


def test_false_loop_closures_in_the_map_have_one_definition_on_the_page_and_in_the_summary(
    false_log: Path, log_reference: SlamSession, tmp_path: Path
) -> None:
    session = log_reference
    false = session.log.false_links(session.evaluation.loop_distance, None)
    assert false is not None
    times, _ = _links(session)
    same_time = {t for t in times[false].tolist() if np.count_nonzero(times == t) > 1}
    assert same_time  # a false link shares its time with a true one (one query, two links)
    expected = {m: map_false_loop_edges(session.log, session.maps[m], session.evaluation)
                for m in MapMode}  # fmt: skip
    # the standard map makes an edge of every link here (no test refuses, no pair repeats)
    assert session.maps[MapMode.STANDARD].num_loop_edges == times.size
    assert expected[MapMode.STANDARD] == int(false.sum()) == 5
    assert all(0 < expected[m] <= int(false.sum()) for m in MapMode)
    # cogmap run writes it into summary.json
    assert main(["run", str(false_log), "--out", str(tmp_path / "run")]) == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    for mode in MapMode:
        assert summary["maps"][mode.value]["false_loop_edges"] == expected[mode]
    assert summary["loop_closures"]["false"] == int(false.sum())
    with running_app(false_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        until(lambda: all(counter(app, f"{m.value}-false") == str(expected[m]) for m in MapMode),
              10, "the three maps' false loop closures")  # fmt: skip
        assert counter(app, "loops-false") == str(int(false.sum()))
        with app.replay.lock:
            page_summary = summary_dict(summary_inputs(app.replay))
        for mode in MapMode:
            assert page_summary["maps"][mode.value]["false_loop_edges"] == expected[mode]
        assert "made from a link the ground truth calls false" in app.counters_html.content
        # a δ change rebuilds only the compact map: the others keep their figure
        app.type_param("delta", "8")
        wait(app)
        compact = session.rebuild(LOG_MAP_PARAMS.with_changes(delta=8.0))[MapMode.COMPACT]
        changed = map_false_loop_edges(session.log, compact, session.evaluation)
        until(lambda: counter(app, "compact-false") == str(changed), 10, "δ = 8")
        for mode in (MapMode.STANDARD, MapMode.SCENE_INTEGRATION):
            assert counter(app, f"{mode.value}-false") == str(expected[mode])


def test_false_links_are_counted_up_to_where_the_replay_is(
    false_log: Path, log_reference: SlamSession
) -> None:
    session = log_reference
    false = session.log.false_links(session.evaluation.loop_distance, None)
    assert false is not None
    times, _ = _links(session)
    with running_app(false_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        app.replay.seek(300.0)
        wait(app)
        k = bisect.bisect_right(session.log.frame_time, 300.0)
        end = session.log.frame_time[k - 1]
        before = times <= end
        assert 0 < before.sum() < times.size and 0 < false[before].sum() < false.sum()
        until(lambda: counter(app, "loops-detected") == str(int(before.sum())), 10, "links")
        until(lambda: counter(app, "loops-false") == str(int(false[before].sum())), 10, "false")
        partial = session.rebuild(LOG_MAP_PARAMS, frames=k, finish=False)
        for mode in MapMode:
            figure = map_false_loop_edges(session.log, partial[mode], session.evaluation)
            until(lambda m=mode, f=figure: counter(app, f"{m.value}-false") == str(f), 10)


def test_counters_say_where_the_links_went(false_log: Path, log_reference: SlamSession) -> None:
    session = log_reference
    times, targets = _links(session)
    with running_app(false_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        for mode in MapMode:
            cmap = session.maps[mode]
            c = cmap.counters
            _, refused = link_resolution(cmap)
            refused_links = sum((t, g) in refused for t, g in zip(times, targets, strict=True))
            made = c.links - refused_links - c.duplicate_links
            until(lambda m=mode, n=c.links: counter(app, f"{m.value}-links") == str(n), 10)
            assert counter(app, f"{mode.value}-duplicates") == str(c.duplicate_links)
            assert counter(app, f"{mode.value}-refused_links") == str(refused_links)
            assert counter(app, f"{mode.value}-made") == str(made)
            drawn_loops = int(np.count_nonzero(cmap.snapshot().edge_kind == 1))
            assert counter(app, f"{mode.value}-removed") == str(made - drawn_loops)
            assert counter(app, f"{mode.value}-loops") == str(cmap.num_loop_edges)
        content = app.counters_html.content
        assert "duplicates (pair already joined)" in content
        assert "refused by the relocalisation test" in content
        view_log = app.cluster_log_html(MapMode.COMPACT, app.replay.session.maps[MapMode.COMPACT])
        assert "<th>links</th>" in view_log and "<th>edges</th>" not in view_log


def test_the_size_chart_follows_the_replay_and_a_new_bag(
    short_bag: Path, false_log: Path, reference: SlamSession
) -> None:
    """Item 1: the x axis spans the data so far (a round number above it), also in a tab open
    during the replay; a new bag starts it again; the top y label has room."""
    from app.server.chart import x_end

    assert [x_end(t) for t in (0.0, 0.5, 3.7, 37.0, 67.2, 825.0)] == [1, 1, 4, 40, 80, 1000]
    folders = [short_bag.parent, false_log.parent]
    with running_app(short_bag, autoplay=False, data_dirs=folders) as app:
        wait(app)
        app.replay.seek(37.0)
        wait(app)
        until(lambda: app.chart.scales["x"]["range"] == (0.0, 40.0), 10, "x to 40 s")
        assert max(app.chart.data[0]) == pytest.approx(app.replay.data_time, abs=1e-6)
        app.replay.play()
        wait(app)
        end = reference.log.frame_time[-1]
        until(lambda: app.chart.scales["x"]["range"] == (0.0, x_end(end)), 10, "x to the end")
        assert app.chart.scales["y"]["range"][1] >= max(
            reference.maps[m].num_edges for m in MapMode
        )
        assert app.chart.padding[0] >= 12  # room above the top y label
        assert app.chart.axes[1]["size"] >= 60  # and left of the axis for "3,000"
        listed = f"{false_log.parent.name}/{false_log.name}"
        assert listed in app.refresh_bags()
        assert app.open_bag(listed)
        wait(app)
        log_end = app.replay.session.log.frame_time[-1]
        until(lambda: app.chart.scales["x"]["range"] == (0.0, x_end(log_end)), 10, "new bag")
        assert max(app.chart.data[0]) == pytest.approx(app.replay.data_time, abs=1e-6)
        assert max(app.chart.data[1]) == app.replay.session.maps[MapMode.STANDARD].num_vertices
