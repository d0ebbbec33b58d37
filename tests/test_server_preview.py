"""Previews of slow rebuilds (issue 27 part 4): shown first, marked, never adopted, then exact.

A preview is only drawn (:mod:`app.server.preview`); the map adopted after it is exactly what
``SlamSession.rebuild`` and ``cogmap run`` build.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import app.server.preview as preview_module
from app.server.panels.parameters import built_content
from app.server.preview import compact_preview, make_preview, preview_difference
from app.server.replay_state import RebuildRecord
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.config import MapParams
from cogmap_core.events import CreateVertex, MapEvent, Odometry
from cogmap_core.geometry import compose_scalar, inverse_scalar
from cogmap_core.neighborhood_fields import is_novel
from cogmap_core.schedule import same_schedule
from cogmap_core.slam import SlamSession
from tests import test_server_support as support
from tests.test_server_support import assert_same_map, running_app

short_bag = support.short_bag
reference = support.reference


def straight_line(mode: MapMode, params: MapParams) -> CognitiveMap:
    """Eleven proposed vertices 0.1 m apart on a straight line (no loop closure)."""
    events: list[MapEvent] = [CreateVertex(0.0, 0, 0)]
    for k in range(1, 11):
        events += [Odometry(k - 0.5, 0.1, 0.0), CreateVertex(float(k), k, k)]
    cmap = CognitiveMap(mode, params)
    cmap.apply_all(events)
    return cmap


def largest_shift(preview: CognitiveMap, exact: CognitiveMap) -> float:
    """The largest distance between a vertex of ``exact`` and where ``preview`` places its id."""
    return max(
        float(np.hypot(*(preview.vertex_pose(v)[:2] - exact.vertex_pose(v)[:2])))
        for v in exact.graph.live_ids().tolist()
    )


def test_a_straight_line_keeps_every_third_vertex_like_the_compact_map() -> None:
    # the paper's field: a vertex once 0.2746 m are driven, here every 0.3 m (ids 0, 3, 6, 9)
    params = MapParams()
    standard = straight_line(MapMode.STANDARD, params)
    preview = compact_preview(standard, params)
    exact = straight_line(MapMode.COMPACT, params)
    assert standard.num_vertices == 11
    assert preview.graph.live_ids().tolist() == [0, 3, 6, 9]
    assert exact.graph.live_ids().tolist() == [0, 3, 6, 9]
    snap = preview.snapshot()
    assert snap.edge_from.tolist() == [0, 3, 6] and snap.edge_to.tolist() == [3, 6, 9]
    assert (snap.edge_kind == EdgeKind.SEQUENTIAL).all()
    np.testing.assert_allclose(snap.edge_rel, [[0.3, 0.0, 0.0]] * 3, atol=1e-12)
    np.testing.assert_allclose(preview.vertex_pose(10), [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(preview.current_pose(), standard.current_pose(), atol=1e-12)
    assert preview.counters.declined == 7
    shift, count = preview_difference(preview, exact)
    assert shift == pytest.approx(0.0, abs=1e-12) and count == 0
    # a larger delta keeps fewer: (1 + 10 d) > 8 from d > 0.7 m: ids 0 and 8
    wide = compact_preview(standard, params.with_changes(delta=8.0))
    assert wide.graph.live_ids().tolist() == [0, 8]
    # every id stays where the standard map has it (through the vertex it merged into)
    assert preview_difference(wide, exact) == (pytest.approx(0.0, abs=1e-12), -2)


def test_the_preview_of_the_reference_follows_the_neighborhood_field(
    reference: SlamSession,
) -> None:
    standard = reference.maps[MapMode.STANDARD]
    params = MapParams(delta=6.0)
    preview = compact_preview(standard, params)
    snap, full = preview.snapshot(), standard.snapshot()
    rows = np.searchsorted(full.vertex_ids, snap.vertex_ids)
    np.testing.assert_array_equal(full.vertex_ids[rows], snap.vertex_ids)
    np.testing.assert_array_equal(snap.poses, full.poses[rows])  # the standard map's poses
    kept = set(snap.vertex_ids.tolist())
    last = None
    for vid, pose in zip(full.vertex_ids.tolist(), full.poses.tolist(), strict=True):
        if last is not None:
            rel = compose_scalar(inverse_scalar(last), pose)
            assert is_novel(rel, params.alpha, params.beta, params.delta) == (vid in kept)
        if vid in kept:
            last = pose
    pairs = {frozenset(p) for p in zip(snap.edge_from.tolist(), snap.edge_to.tolist(), strict=True)}
    assert len(pairs) == snap.edge_from.size  # no duplicates, no self-loops
    assert all(len(p) == 2 for p in pairs)
    assert preview.num_vertices + preview.counters.declined == standard.num_vertices
    assert preview_difference(standard, standard) == (0.0, 0)


def test_only_the_schedule_and_the_neighborhood_field_have_previews(
    reference: SlamSession,
) -> None:
    maps = reference.maps
    paper = MapParams()
    standard = maps[MapMode.STANDARD]
    for mode in MapMode:
        shown = make_preview(mode, maps[mode], standard, paper.with_changes(t_total=40.0))
        assert shown is not None and shown.cmap is maps[mode] and shown.how == "schedule"
        assert make_preview(mode, maps[mode], standard, paper.with_changes(huber_scale=0.2)) is None
        assert make_preview(mode, maps[mode], standard, paper) is None
    fields = make_preview(MapMode.COMPACT, maps[MapMode.COMPACT], standard, MapParams(alpha=20.0))
    assert fields is not None and fields.how == "fields"
    both = paper.with_changes(delta=6.0, t_total=40.0)
    assert make_preview(MapMode.COMPACT, maps[MapMode.COMPACT], standard, both) is None
    # the standard map must be built for the new parameters already
    old_standard = CognitiveMap(MapMode.STANDARD, paper.with_changes(t_total=40.0))
    new = paper.with_changes(delta=6.0)
    assert make_preview(MapMode.COMPACT, maps[MapMode.COMPACT], old_standard, new) is None


def test_the_page_says_preview_then_the_difference(reference: SlamSession) -> None:
    maps = reference.maps.maps
    shown = built_content(maps, None, {MapMode.COMPACT: "the map before the new schedule"}, {})
    assert "<b>compact: preview</b> (the map before the new schedule) until the exact" in shown
    after = built_content(maps, None, {}, {MapMode.COMPACT: (0.0136, 4)})
    assert (
        "compact: exact map shown; the preview differed by 0.014 m (largest vertex shift), +4 "
        in after
    )
    assert "cogmap-preview" not in built_content(maps, None)
    record = RebuildRecord(MapParams(), 1, 10.0)
    record.published[MapMode.COMPACT] = 12.5
    assert record.preview_latency(MapMode.COMPACT) == 2.5
    record.previewed[MapMode.COMPACT] = 10.25
    assert (
        record.preview_latency(MapMode.COMPACT) == 0.25 and record.latency(MapMode.COMPACT) == 2.5
    )


class Shown:
    """What the scene was handed at each publish, and the page's rebuild note after each update."""

    def __init__(self, app: Any) -> None:
        self.app = app
        self.publishes: list[dict[str, Any]] = []
        self.notes: list[str] = []
        publish = app.streamer.publish
        update = app.update_status

        def published(maps: dict[MapMode, CognitiveMap], *args: Any, **kwargs: Any) -> None:
            publish(maps, *args, **kwargs)
            session = app.replay.session.maps.maps
            self.publishes.append(
                {
                    "maps": dict(maps),
                    "previewed": set(kwargs.get("previewed", ())),
                    "session": dict(session),
                    "labels": {m: app.streamer.layers[m].label.text for m in MapMode},
                }
            )

        def updated(force: bool = False) -> None:
            update(force)
            self.notes.append(app.built_html.content)

        app.streamer.publish = published
        app.update_status = updated

    def previews(self) -> list[dict[str, Any]]:
        """The publishes that drew a preview."""
        return [p for p in self.publishes if p["previewed"]]


def test_a_delta_change_previews_the_compact_map_then_shows_the_exact_one(
    short_bag: Path, reference: SlamSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(preview_module, "PREVIEW_AFTER_S", 0.0)
    params = MapParams(delta=6.0)
    with running_app(short_bag) as app:
        assert app.wait_idle(60)
        standard = app.replay.session.maps[MapMode.STANDARD]
        expected_preview = compact_preview(standard, params)
        shown = Shown(app)
        app.param_sliders["delta"].value = 6.0
        assert app.wait_idle(60)
        record = app.replay.rebuilds[-1]
        assert record.completed and record.params == params
        assert record.how == {
            MapMode.COMPACT: "built",
            MapMode.SCENE_INTEGRATION: "kept",
            MapMode.STANDARD: "kept",
        }
        assert set(record.previewed) == {MapMode.COMPACT}
        assert (
            record.requested < record.previewed[MapMode.COMPACT] < record.published[MapMode.COMPACT]
        )
        assert record.preview_latency(MapMode.COMPACT) < record.latency(MapMode.COMPACT)
        # the preview: drawn and named so, the session's map the old one meanwhile
        drawn = shown.previews()  # (the figures worker may draw the scene again meanwhile)
        first = drawn[0]
        assert first["previewed"] == {MapMode.COMPACT}
        preview = first["maps"][MapMode.COMPACT]
        assert all(p["maps"][MapMode.COMPACT] is preview for p in drawn)
        assert preview is not first["session"][MapMode.COMPACT]
        assert first["session"][MapMode.COMPACT].params.delta == 3.746
        assert first["labels"][MapMode.COMPACT] == "compact · preview"
        assert first["labels"][MapMode.STANDARD] == "standard"
        assert_same_map(preview, expected_preview)
        assert any("<b>compact: preview</b> (neighborhood fields" in n for n in shown.notes)
        # never adopted: no publish had it in the session, the exact map follows
        assert all(preview is not cmap for p in shown.publishes for cmap in p["session"].values())
        exact = app.replay.session.maps[MapMode.COMPACT]
        assert_same_map(exact, reference.rebuild(params)[MapMode.COMPACT])
        last = shown.publishes[-1]
        assert last["previewed"] == set() and last["maps"][MapMode.COMPACT] is exact
        assert last["labels"][MapMode.COMPACT] == "compact"
        assert app.replay.previews == {}
        # the difference, computed here another way
        shift, count = record.preview_difference[MapMode.COMPACT]
        assert count == preview.num_vertices - exact.num_vertices
        assert (
            count
            == expected_preview.num_vertices
            - reference.rebuild(params)[MapMode.COMPACT].num_vertices
        )
        assert math.isclose(shift, largest_shift(preview, exact), rel_tol=1e-12)
        assert f"the preview differed by {shift:.3f} m (largest vertex shift), {count:+d}" in (
            app.built_html.content
        )
        # a map whose last build was fast enough is not previewed
        monkeypatch.setattr(preview_module, "PREVIEW_AFTER_S", 1e9)
        app.param_sliders["delta"].value = 5.0
        assert app.wait_idle(60)
        record = app.replay.rebuilds[-1]
        assert record.how[MapMode.COMPACT] == "built" and record.previewed == {}
        assert record.preview_latency(MapMode.COMPACT) == record.latency(MapMode.COMPACT)
        assert "cogmap-preview" not in app.built_html.content


def test_a_t_total_change_previews_the_maps_shown(
    short_bag: Path, reference: SlamSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(preview_module, "PREVIEW_AFTER_S", 0.0)
    with running_app(short_bag) as app:
        app.show_maps(MapMode.COMPACT, MapMode.STANDARD, MapMode.SCENE_INTEGRATION)
        assert app.wait_idle(60)
        replay = app.replay
        log = replay.session.log
        t_total = next(  # a schedule of its own: every map is built
            t
            for t in (10.0, 3.0, 1.0)
            if not same_schedule(
                log, replay.cursor, replay.at_end, MapParams(), MapParams(t_total=t)
            )
        )
        params = MapParams(t_total=t_total)
        before = dict(app.replay.session.maps.maps)
        shown = Shown(app)
        app.param_sliders["t_total"].value = t_total
        assert app.wait_idle(60)
        record = app.replay.rebuilds[-1]
        assert record.completed and record.how == {m: "built" for m in MapMode}
        assert set(record.previewed) == set(MapMode)
        drawn = shown.previews()
        assert drawn[0]["previewed"] == set(MapMode)
        for mode in MapMode:
            assert drawn[0]["maps"][mode] is before[mode]  # the map shown: no computation
            assert drawn[0]["labels"][mode] == f"{mode.value.replace('_', ' ')} · preview"
            exact = app.replay.session.maps[mode]
            # until its exact map is drawn, a map is its preview; then the exact map, named so
            for p in shown.publishes[shown.publishes.index(drawn[0]) :]:
                if mode in p["previewed"]:
                    assert p["maps"][mode] is before[mode] and p["session"][mode] is before[mode]
                else:
                    assert p["maps"][mode] is exact and p["labels"][mode] == mode.value.replace(
                        "_", " "
                    )
            assert_same_map(exact, reference.rebuild(params)[mode])
            assert record.previewed[mode] < record.published[mode]
            shift, count = record.preview_difference[mode]
            assert count == before[mode].num_vertices - exact.num_vertices
            assert math.isclose(shift, largest_shift(before[mode], exact), rel_tol=1e-12)
        assert app.replay.previews == {}
        assert "the map before the new schedule" in "".join(shown.notes)
