"""Scene integration on the event patterns the front end emits (paper, "Scene Integration").

Revisits come as *link + set current vertex* on old vertices, with the occasional new vertex the
front end proposes on known ground; first visits come as *create vertex*. The scripted loop below
produces exactly those patterns (the recorded streams of generated bags are replayed in
``test_map_fidelity.py``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core.cognitive_map import CognitiveMap, MapSnapshot
from cogmap_core.config import MapParams
from cogmap_core.geometry import between
from cogmap_core.map_graph import EdgeKind
from tests.mapscript import Script

HALF_PI = math.pi / 2
STEP = 0.05  # m between front-end experiences, as dense as the front end's
SIDE = 20  # steps per side of the 1 m square
LAP = 4 * SIDE
DT = 0.2  # s per step: a lap takes 16 s, more than integration_min_age (10 s)
NO_GATE = {"gate_position": 1e9, "gate_heading": 1e9}
PAPER_MERGE = {"integration_keeps_evidence": 0.0}  # a merged run's edges re-attached, no more


class SquareLoop:
    """A robot lapping a 1 m square, driven event by event like the front end drives the map."""

    def __init__(self, dt: float = DT) -> None:
        self.s = Script(dt)
        self.step = 0
        self.first: list[int] = [self.s.create()]  # first-visit vertex at each step of lap 1
        self.new: list[int] = []  # vertices proposed on later laps

    def advance(self) -> None:
        """Move to the next step of the square (turning left at the corners)."""
        corner = self.step > 0 and self.step % SIDE == 0
        self.s.move(STEP, HALF_PI if corner else 0.0)
        self.step += 1

    def first_lap(self) -> None:
        while self.step < LAP - 1:
            self.advance()
            self.first.append(self.s.create())
        self.advance()  # back at the start

    def known_lap(self, propose: set[int] = frozenset(), chains: set[int] = frozenset()) -> None:
        """One lap on known ground: relocalise at each step, except where a vertex is proposed.

        ``propose``: lap positions where the front end proposes one new vertex (then relocalises
        at the next step: a run of one, case A). ``chains``: positions where it keeps proposing
        (case C).
        """
        for _ in range(LAP):
            position = self.step % LAP
            if position in propose or position in chains:
                self.new.append(self.s.create())
            else:
                self.s.relocalise(self.first[position])
            self.advance()


def build(mode: str, script: Script, **params: float) -> CognitiveMap:
    cmap = CognitiveMap(mode, MapParams(**params))
    cmap.apply_all(script.events)
    cmap.finish()
    return cmap


def alive(cmap: CognitiveMap) -> list[int]:
    return cmap.snapshot().vertex_ids.tolist()


# ------------------------------------------------------------------------------------------
# a corridor re-walked keeps its size
# ------------------------------------------------------------------------------------------


def test_loop_rewalked_five_times_keeps_its_vertex_count():
    loop = SquareLoop()
    loop.first_lap()
    sizes: dict[str, list[int]] = {"standard": [], "scene_integration": [], "compact": []}
    events_after_lap = [len(loop.s.events)]
    for lap in range(5):
        # the front end proposes a vertex now and then, and a chain of three once per lap
        loop.known_lap(propose={7 + lap, 31, 52 + 2 * lap}, chains={65, 66, 67})
        events_after_lap.append(len(loop.s.events))
    for mode in sizes:
        cmap = CognitiveMap(mode)
        done = 0
        for end in events_after_lap:
            cmap.apply_all(loop.s.events[done:end])
            done = end
            cmap.optimize_now()  # settle, as the end of a cluster does
            sizes[mode].append(cmap.num_vertices)
    assert sizes["standard"] == [LAP + 6 * k for k in range(6)]  # every proposal kept
    assert sizes["scene_integration"] == [LAP] * 6  # every revisit vertex merged
    compact = sizes["compact"]
    assert max(compact) - min(compact) <= 1, compact
    assert compact[0] < LAP / 3  # neighborhood fields keep about one vertex in six


def test_revisit_vertex_merges_into_the_old_place_case_a():
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap(propose={33})  # position 33 is on the second side, x = 1, y = 0.65
    v = loop.new[0]
    standard = build("standard", loop.s)
    assert v in alive(standard)
    cmap = build("scene_integration", loop.s, **PAPER_MERGE)
    assert alive(cmap) == loop.first
    kept, offset = cmap.resolve(v)
    assert kept == loop.first[33]
    np.testing.assert_allclose(offset, [0.0, 0.0, 0.0], atol=1e-9)
    assert cmap.integrated_vertices == 1
    # the sequential edge into the revisit and its loop closure collapse onto the old edges
    assert cmap.num_edges == LAP  # the lap's 80 sequential edges, the closing edge 79 -> 0


@pytest.mark.parametrize("mode", ["scene_integration", "compact"])
def test_a_run_closed_after_spinning_back_is_judged_from_where_the_robot_was(mode):
    # On known ground the robot turns on the spot, the front end proposes two vertices (0.4 and
    # 0.8 rad turned), the robot turns back, is re-localised on the first of them (young: the
    # run stays open) and then on the old vertex it started from. The closing link was measured
    # from the first new vertex; judged from the run's last one it would disagree by 0.4 rad.
    loop = SquareLoop()
    loop.first_lap()
    s = loop.s
    for _ in range(33):
        s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    old = loop.first[33]
    s.relocalise(old)
    s.move(0.0, 0.4)
    a = s.create()
    s.move(0.0, 0.4)
    b = s.create()
    s.move(0.0, -0.4)
    s.relocalise(a)
    s.move(0.0, -0.4)
    s.relocalise(old)
    cmap = build(mode, s, **PAPER_MERGE)
    assert a not in alive(cmap) and b not in alive(cmap)
    assert cmap.resolve(a)[0] == cmap.resolve(old)[0] == cmap.resolve(b)[0]


def test_a_merged_revisit_vertex_leaves_its_chain_as_evidence():
    """Case A with the run's evidence kept: its two edges 32 -> v -> 34, composed, join 32 and
    34 -- optimised, held, not drawn."""
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap(propose={33})
    cmap = build("scene_integration", loop.s)
    assert alive(cmap) == loop.first and cmap.integrated_vertices == 1
    assert cmap.num_edges == LAP + 1 and len(cmap.snapshot().edge_from) == LAP
    graph = cmap.graph
    k = graph.edge_between(loop.first[32], loop.first[34])
    assert graph.edge_evidence[k] and graph.edge_held[k] and graph.edge_from[k] == loop.first[32]
    truth = between(loop.s.truth[loop.first[32]], loop.s.truth[loop.first[34]])
    np.testing.assert_allclose(graph.edge_rel[k], truth, atol=1e-9)  # exact odometry


def test_a_run_that_spun_back_leaves_the_chain_it_walked_as_evidence():
    """Lap 2 proposes a vertex v at position 33, turns on the spot there (the front end proposes
    w, 0.4 rad turned), turns back, is re-localised on v (young: the run stays open) and drives
    on to 34, where it is recognised. The closing link was measured from v, so the chain the run
    walked is 32 -> v -> 34 (w hangs off it): its evidence joins 32 and 34, as in case A."""
    loop = SquareLoop()
    loop.first_lap()
    s = loop.s
    while loop.step < LAP + 33:
        s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    v = s.create()
    s.move(0.0, 0.4)
    w = s.create()
    s.move(0.0, -0.4)
    s.relocalise(v)
    loop.advance()
    loop.known_lap()
    cmap = build("scene_integration", s)
    assert alive(cmap) == loop.first and cmap.integrated_vertices == 2
    graph = cmap.graph
    k = graph.edge_between(loop.first[32], loop.first[34])
    assert graph.edge_evidence[k] and graph.edge_held[k] and graph.edge_from[k] == loop.first[32]
    truth = between(s.truth[loop.first[32]], s.truth[loop.first[34]])
    np.testing.assert_allclose(graph.edge_rel[k], truth, atol=1e-9)  # exact odometry
    assert cmap.resolve(w)[0] == loop.first[33]


def test_several_revisit_vertices_onto_one_old_vertex_case_b():
    loop = SquareLoop()
    loop.first_lap()
    loop.s.relocalise(loop.first[0])  # back at the start, recognised
    for _ in range(3):  # it spins on the spot; the front end proposes a vertex at each new
        loop.s.move(0.0, 0.3)  # view, then recognises the place again
        loop.new.append(loop.s.create())
    loop.s.move(0.0, -0.9)
    loop.known_lap()
    cmap = build("scene_integration", loop.s)
    assert alive(cmap) == loop.first
    assert {cmap.resolve(v)[0] for v in loop.new} == {loop.first[0]}
    for v in loop.new:  # each keeps its own heading, as a pose in the absorber's frame
        expected = between(loop.s.truth[loop.first[0]], loop.s.truth[v])
        np.testing.assert_allclose(cmap.resolve(v)[1], expected, atol=1e-9)
        assert abs(expected[2]) > 0.2


def test_chain_of_revisit_vertices_removed_case_c():
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap(chains=set(range(44, 56)))  # twelve proposals in a row, then recognised
    cmap = build("scene_integration", loop.s, **PAPER_MERGE)
    assert alive(cmap) == loop.first
    assert [cmap.resolve(v)[0] for v in loop.new] == [loop.first[p] for p in range(44, 56)]
    assert cmap.num_loop_edges == 1  # only the lap's closing link 79 -> 0 is left
    standard = build("standard", loop.s)
    assert standard.num_vertices == LAP + 12
    kept = build("scene_integration", loop.s)  # the twelve's chain 43 -> ... -> 56 kept
    assert alive(kept) == loop.first and kept.num_loop_edges == 2
    assert kept.graph.edge_evidence[kept.graph.edge_between(loop.first[43], loop.first[56])]


def test_revisits_recognised_by_links_alone_are_integrated():
    """A front end that links without moving the robot (odometry + place recognition logs)."""
    loop = SquareLoop()
    loop.first_lap()
    for _ in range(LAP):
        position = loop.step % LAP
        if position % 4 == 2:  # a new vertex every 4 steps on known ground ...
            loop.new.append(loop.s.create())
        if position % 8 == 0:  # ... and the place recognised every 8: a link, no set current
            loop.s.link(loop.first[position])
        loop.advance()
    loop.s.link(loop.first[0])
    standard = build("standard", loop.s)
    assert standard.num_vertices == LAP + LAP // 4
    cmap = build("scene_integration", loop.s)
    assert alive(cmap) == loop.first  # every run between two links re-walked known ground
    for v in loop.new:  # each merged into the old vertex at its place
        kept, offset = cmap.resolve(v)
        np.testing.assert_allclose(
            between(loop.s.truth[kept], loop.s.truth[v])[:2], offset[:2], atol=1e-9
        )
        assert np.hypot(*offset[:2]) <= 0.5 * STEP + 1e-9


def links_alone_lap(false_at: int | None = None) -> SquareLoop:
    """Lap 2 of a front end that links without moving the robot: a new vertex every 4 steps,
    the place recognised every 8. ``false_at``: that lap position's link names the place half a
    lap back instead (across the square, a false match)."""
    loop = SquareLoop()
    loop.first_lap()
    for _ in range(LAP):
        position = loop.step % LAP
        if position % 4 == 2:
            loop.new.append(loop.s.create())
        if position % 8 == 0:
            named = (position - LAP // 2) % LAP if position == false_at else position
            loop.s.link(loop.first[named])
        loop.advance()
    loop.s.link(loop.first[0])
    return loop


def test_the_links_a_merged_run_rests_on_are_held():
    """Each run between two links closes on one link and opens on the one before: once merged,
    both are held (no hypothesis may reject them while the merge stands); no map without scene
    integration holds a link."""
    loop = links_alone_lap()
    for mode, holds in (("standard", False), ("scene_integration", True)):
        graph = build(mode, loop.s, **PAPER_MERGE).graph
        loops = graph.edge_kind[: graph.num_edges_total] == EdgeKind.LOOP_CLOSURE
        assert int(loops.sum()) == 11  # lap 1's closing link and one every 8 steps of lap 2
        assert graph.edge_held[: graph.num_edges_total].tolist() == (loops & holds).tolist()


def test_with_the_runs_evidence_kept_the_evidence_is_held_in_the_closing_links_place():
    """Each run between two links, merged, leaves one evidence edge from the vertex its first
    vertex hung off to the place its closing link named, held; the link that opened it stays,
    held too (lap 1's closing link 79 -> 0 opened the first run)."""
    loop = links_alone_lap()
    graph = build("scene_integration", loop.s).graph
    live = graph.edge_alive[: graph.num_edges_total]
    evidence = graph.edge_evidence[: graph.num_edges_total] & live
    ends = sorted(
        (int(graph.edge_from[k]), int(graph.edge_to[k])) for k in np.flatnonzero(evidence)
    )
    # each run after the first hangs off the vertex the previous run's last one merged into
    first = loop.first
    assert ends == sorted(
        [(first[79], first[8])] + [(first[p - 2], first[(p + 8) % LAP]) for p in range(8, LAP, 8)]
    )
    links = live & ~evidence & (graph.edge_kind[: graph.num_edges_total] == EdgeKind.LOOP_CLOSURE)
    assert [(int(graph.edge_from[k]), int(graph.edge_to[k])) for k in np.flatnonzero(links)] == [
        (first[79], first[0])
    ]
    held = graph.edge_held[: graph.num_edges_total] & live
    assert held.tolist() == (evidence | links).tolist()


def test_a_run_opened_by_a_rejected_link_is_not_integrated():
    """The link that re-localised the robot where a run began must agree with the map too.

    The link at lap position 48, (0.6, 1), names position 8, (0.4, 0): the optimisation
    rejects it. It closes the run before it (positions 42 and 46: its closing link disagrees)
    and opens the run after it (50 and 54, closed by the true link at 56): both stay, however
    well the true link that closes the second agrees.
    """
    loop = links_alone_lap(false_at=48)
    cmap = build("scene_integration", loop.s, **NO_GATE)
    kept = set(alive(cmap))
    assert [v for v in loop.new if v in kept] == loop.new[10:14]  # positions 42 to 54
    assert set(loop.first) <= kept
    assert int(cmap.rejected_loop_edges().sum()) == 1


# ------------------------------------------------------------------------------------------
# what is never removed
# ------------------------------------------------------------------------------------------


def detour_lap(loop: SquareLoop) -> list[int]:
    """A lap that leaves the square at the corner (1, 0), explores 3 m, returns at (1, 1)."""
    explored = []
    while loop.step % LAP != SIDE:  # known ground up to the corner (1, 0)
        loop.s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    loop.s.relocalise(loop.first[SIDE])
    for leg, turn in ((SIDE, 0.0), (SIDE, HALF_PI), (SIDE, HALF_PI)):
        for k in range(leg):
            loop.s.move(STEP, turn if k == 0 else 0.0)
            explored.append(loop.s.create())  # first visits: (1.05, 0) ... (1.05, 1) ... (1, 1)
    # it comes back onto the square at (1, 1), facing west, and is recognised there
    loop.step = 2 * SIDE
    loop.s.relocalise(loop.first[2 * SIDE])
    loop.advance()
    while loop.step % LAP != 0:
        loop.s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    return explored


def test_frontier_and_first_visit_vertices_survive():
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap()
    loop.s.move(0.0, 0.0)
    explored = detour_lap(loop)
    cmap = build("scene_integration", loop.s)
    kept = set(alive(cmap))
    assert explored[0] in kept  # the frontier vertex, where the robot leaves known ground
    # every first visit survives, also the last one, 5 cm short of the place it came back to
    assert [v for v in explored if v not in kept] == []
    compact = build("compact", loop.s)
    compact_explored = [v for v in explored if compact.resolve(v)[0] == v]
    assert explored[0] not in compact_explored  # declined by neighborhood fields, not merged
    assert len(compact_explored) >= 8  # the new 3 m keep their compact vertices


def test_two_first_visit_vertices_are_never_merged():
    """Into a dead end and back out: the way out passes the way in's vertices 2-4 s later."""
    s = Script(dt=0.2)
    way_in = [s.create()]
    for _ in range(10):
        s.move(STEP)
        way_in.append(s.create())
    s.move(0.0, math.pi)  # U-turn at the dead end
    way_out = []
    for k in range(10):
        s.move(STEP)
        way_out.append(s.create())
        s.relocalise(way_in[9 - k])  # recognised on what it mapped seconds ago
    cmap = build("scene_integration", s)
    assert alive(cmap) == way_in + way_out
    assert cmap.integrated_vertices == 0


# ------------------------------------------------------------------------------------------
# each knob matters
# ------------------------------------------------------------------------------------------


def lap_with_offset_revisit(lateral: float) -> SquareLoop:
    """Lap 2 proposes a vertex ``lateral`` m to the left of the old route at position 10."""
    loop = SquareLoop()
    loop.first_lap()
    while loop.step % LAP != 10:
        loop.s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    loop.s.move(0.0, HALF_PI)
    loop.s.move(lateral)
    loop.s.move(0.0, -HALF_PI)
    loop.new.append(loop.s.create())
    loop.s.move(0.0, -HALF_PI)
    loop.s.move(lateral)
    loop.s.move(0.0, HALF_PI)
    loop.advance()
    while loop.step % LAP != 0:
        loop.s.relocalise(loop.first[loop.step % LAP])
        loop.advance()
    return loop


def test_integration_radius_decides_how_far_a_revisit_may_lie():
    loop = lap_with_offset_revisit(lateral=0.07)
    v = loop.new[0]
    assert v not in alive(build("scene_integration", loop.s, integration_radius=0.1))
    assert v in alive(build("scene_integration", loop.s, integration_radius=0.05))


def test_integration_max_residual_keeps_revisits_whose_closing_link_disagrees():
    # the closing link claims the robot is at position 35 (0.2 m ahead): it contradicts
    # odometry, and the optimisation cannot satisfy it (0.15 m ahead left 0.101 m after the
    # paper's Huber and 0.0995 m after the robust loop model: on the 0.1 m limit either way)
    loop, _ = lap_closed_by_a_false_link()
    v = loop.new[0]
    kept = build("scene_integration", loop.s, **NO_GATE)
    assert v in alive(kept)
    # (the paper's Huber: the robust loop model would reject the link and split the merge, below)
    merged = build(
        "scene_integration", loop.s, integration_max_residual=1.0, loop_model=0, **NO_GATE
    )
    assert v not in alive(merged)


def lap_closed_by_a_false_link() -> tuple[SquareLoop, int]:
    """Lap 2 proposes one vertex at position 30; the link after it names position 35 instead of
    31 (0.2 m ahead, a false match). Returns the loop and the index of that link's event."""
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap(propose={30})
    events = loop.s.events
    k = next(i for i, e in enumerate(events) if getattr(e, "target", None) == loop.first[31])
    events[k] = type(events[k])(events[k].time, loop.first[35], events[k].relative_rad)
    events[k + 1] = type(events[k + 1])(events[k + 1].time, loop.first[35], 0.0)
    return loop, k


def edge_measurements(snapshot: MapSnapshot) -> dict[tuple[int, int], list[float]]:
    """A snapshot's edges: (from, to) -> measurement."""
    ends = zip(snapshot.edge_from.tolist(), snapshot.edge_to.tolist(), strict=True)
    return dict(zip(ends, snapshot.edge_rel.tolist(), strict=True))


@pytest.mark.parametrize("evidence", [0.0, 1.0])
def test_a_false_link_merged_and_later_rejected_is_undone(evidence):
    """With ``integration_max_residual`` 1 m the false link agrees with the map when it closes
    the run, and the run's vertex is merged at once, resting on it; the optimisation then rejects
    the link, so the merge is split: the vertex is live again with its edges as measured, and
    the map is the standard map (same vertices, same edges and measurements, same poses)."""
    loop, k = lap_closed_by_a_false_link()
    v = loop.new[0]
    params = MapParams(integration_max_residual=1.0, integration_keeps_evidence=evidence, **NO_GATE)
    cmap = CognitiveMap("scene_integration", params)
    cmap.apply_all(loop.s.events[: k + 2])
    graph = cmap.graph
    assert not graph.alive[v] and not cmap.optimizations
    assert int(np.count_nonzero(graph.edge_held & graph.edge_alive)) == 1
    assert len(cmap.integration.merges) == 1
    cmap.apply_all(loop.s.events[k + 2 :])
    cmap.finish()
    standard = build("standard", loop.s, **params.to_dict())
    assert len(cmap.optimizations) == 1
    assert graph.alive[v] and (cmap.counters.split, cmap.counters.integrated) == (1, 0)
    assert not cmap.integration.merges and not (graph.edge_held & graph.edge_alive).any()
    got, want = cmap.snapshot(), standard.snapshot()
    assert got.vertex_ids.tolist() == want.vertex_ids.tolist()
    assert edge_measurements(got) == edge_measurements(want)
    assert np.abs(got.poses - want.poses).max() < 1e-4
    false_link = graph.edge_between(v, loop.first[35])
    assert cmap.rejected_loop_edges().tolist() == standard.rejected_loop_edges().tolist()
    assert cmap.rejected_loop_edges()[list(cmap.graph.live_edges()).index(false_link)]


def test_integration_min_age_separates_revisits_from_recent_ground():
    loop = SquareLoop(dt=0.1)  # a lap now takes 8 s
    loop.first_lap()
    loop.known_lap(propose={20})
    v = loop.new[0]
    assert v in alive(build("scene_integration", loop.s))  # 8 s < integration_min_age 10 s
    assert v not in alive(build("scene_integration", loop.s, integration_min_age=5.0))


@pytest.mark.parametrize("mode", ["scene_integration", "compact"])
def test_merges_reevaluated_against_the_final_absorber(mode):
    """A revisit of a revisit: lap 3's vertex lands on lap 2's, which lap 2 merged already."""
    loop = SquareLoop()
    loop.first_lap()
    loop.known_lap(propose={12})
    loop.known_lap(propose={12})
    cmap = build(mode, loop.s)
    first_id, second_id = loop.new
    assert cmap.resolve(second_id)[0] == cmap.resolve(first_id)[0]
    assert cmap.resolve(first_id)[0] in loop.first
    np.testing.assert_allclose(cmap.vertex_pose(second_id), cmap.vertex_pose(first_id), atol=1e-9)
