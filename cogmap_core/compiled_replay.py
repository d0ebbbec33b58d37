"""A compiled map replay: the cognitive map's sequential decisions over plain arrays (numba).

Rebuilding a map for new parameters replays the front end's recorded events
(:mod:`cogmap_core.event_file` columns) through :class:`~cogmap_core.cognitive_map.CognitiveMap`.
In pure Python each event costs microseconds; this module runs the common events in one
compiled loop (``@njit(cache=True)``) over the map's own arrays and hands every other event to
the map's Python code, event by event, so the result is the map the Python path builds
(:meth:`CognitiveMap.apply <cogmap_core.cognitive_map.CognitiveMap.apply>` stays the reference).

The compiled loop does, exactly as the Python code does them:

- odometry: the dead-reckoned motion since the current vertex;
- a proposed vertex: the neighborhood field's decision (compact map), the new vertex and its
  sequential edge, or the alias a declined one becomes; scene integration's bookkeeping of the
  open revisit run;
- a link: the relocalisation test (:mod:`~cogmap_core.relocalisation`) when it needs no path
  search, the cluster it joins, the loop-closure edge (or the duplicate it is), and scene
  integration's note of where the robot was re-localised;
- set current: the robot continues from the vertex (its offset and relative angle).

It stops before any event it does not handle, and the map's Python code applies that one:
a cluster that closes (the batch optimisation, scene integration, short edges), a new cluster,
a relocalisation that needs a path search or is refused, a revisit run that opens or closes,
arrays that must grow, and every event that breaks the contract (the Python code raises the
error). Python's lists and dicts the map keeps (adjacency, absorbed ids, the open run's vertices,
the size history) are brought up to date from the compiled loop's logs before that.

Floating point follows CPython: ``math.hypot`` is CPython's own algorithm (not the C library's,
which differs in the last bit now and then), reproduced here; ``%`` on floats, ``cos`` and
``sin`` are the same operations. :func:`available` checks this once per process against
CPython on sample values and refuses the compiled path if anything differs.

numba is optional at run time: without it (or when the check fails) :func:`replay` applies the
events with :meth:`CognitiveMap.apply_all <cogmap_core.cognitive_map.CognitiveMap.apply_all>`.
Compiled code is cached on disk (``NUMBA_CACHE_DIR`` when set; else beside this file when that
is writable; else ``$XDG_CACHE_HOME/cogmap/numba`` or ``~/.cache/cogmap/numba``; caching is off
when none of them is writable), so a new process loads it in a fraction of a second.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core import compiled_loop as loop
from cogmap_core import compiled_search
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.compiled_loop import (
    F_ACC0,
    F_ACC1,
    F_ACC2,
    F_ALPHA,
    F_BETA,
    F_CLUSTER_LAST,
    F_CLUSTER_START,
    F_DELTA,
    F_GATE_DRIFT_HEADING,
    F_GATE_DRIFT_POSITION,
    F_GATE_HEADING,
    F_GATE_POSITION,
    F_HIST_TIME,
    F_LAST_ROTATION,
    F_LAST_TIME,
    F_LINK_TIME,
    F_MIN_AGE,
    F_SIZE,
    F_T_INTERVAL,
    F_T_TOTAL,
    F_TRAVELLED,
    I_AT,
    I_AT_END,
    I_AT_ROBOT,
    I_CLUSTER_COUNT,
    I_CLUSTER_ID,
    I_CLUSTER_OPEN,
    I_CURRENT,
    I_DECLINED,
    I_DECLINES,
    I_DUPLICATES,
    I_HIST_FIRST_CHANGED,
    I_HIST_N,
    I_INTEGRATES,
    I_LINK,
    I_LINK_ACCEPTED,
    I_LINK_TARGET,
    I_LINKS,
    I_N_ABSORBED,
    I_N_EDGE_LOG,
    I_N_RUN,
    I_NUM_EDGES,
    I_NUM_EDGES_TOTAL,
    I_NUM_IDS,
    I_NUM_LOOP_EDGES,
    I_NUM_VERTICES,
    I_PROPOSED,
    I_RUN_OPEN,
    I_SIZE,
    I_STREAK,
    I_TABLE_USED,
)
from cogmap_core.event_file import columns_to_events, events_to_columns
from cogmap_core.events import (
    CreateVertex,
    LinkToVertex,
    MapEvent,
    Odometry,
    SetCurrentVertex,
)
from cogmap_core.geometry import TWO_PI
from cogmap_core.numba_cache import cached_njit

#: Set to "0" to never use the compiled replay (e.g. to time the Python path).
ENV_SWITCH = "COGMAP_COMPILED_REPLAY"


_AVAILABLE: bool | None = None
_REASON: str | None = None


def _load() -> None:
    """Import numba, compile the loop (or load it from the cache) and check it (once)."""
    global _AVAILABLE, _REASON
    _AVAILABLE = False
    try:
        jit = cached_njit(__file__)
    except ImportError:
        _REASON = "numba is not installed"
        return
    try:
        loop.compile_all(jit)
        compiled_search.compile_all(jit)
        _AVAILABLE = _self_check()
        if not _AVAILABLE:
            _REASON = "compiled arithmetic differs from CPython's"
        else:
            _warm_up()
    except Exception as exc:  # a broken numba or LLVM: the Python path still works
        _AVAILABLE = False
        _REASON = f"{type(exc).__name__}: {exc}"
        loop.uncompile()


def available() -> bool:
    """Whether the compiled replay is used: numba imports and computes exactly as CPython.

    Checked once per process (compiling the loop, or loading it from the cache); the
    environment variable ``COGMAP_COMPILED_REPLAY=0`` turns it off.
    """
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return False
    if _AVAILABLE is None:
        _load()
    return bool(_AVAILABLE)


def unavailable_reason() -> str | None:
    """Why the compiled replay is not used (None when it is)."""
    return None if available() else _REASON or f"{ENV_SWITCH}=0"


def _self_check() -> bool:
    """Compare the compiled hypot, wrap, cos and sin with CPython's on sample values."""
    rng = np.random.default_rng(27)
    xs = np.concatenate(
        [rng.normal(0.0, scale, (400, 2)) for scale in (1e-6, 1e-3, 0.1, 1.0, 10.0, 1e3)]
        + [np.array([[0.0, 0.0], [3.0, 4.0], [-0.0, 2.0], [1e-310, 3e-310], [math.pi, -5.0]])]
    )
    got = loop._check(xs)
    want = np.array(
        [
            (
                math.hypot(x, y),
                (x + y + math.pi) % TWO_PI - math.pi,
                math.cos(x),
                math.sin(y),
            )
            for x, y in xs.tolist()
        ]
    )
    return bool(np.array_equal(got, want))


def _warm_up() -> None:
    """Run the compiled loop and path search once, so that a first rebuild compiles neither."""
    events: list[MapEvent] = [
        Odometry(0.1, 0.1, 0.0),
        CreateVertex(0.1, 0, 0),
        Odometry(0.2, 0.1, 0.1),
        CreateVertex(0.2, 1, 1),
        LinkToVertex(0.3, 0, 0.0),
        SetCurrentVertex(0.3, 0, 0.0),
    ]
    cmap = CognitiveMap(MapMode.STANDARD)
    CompiledReplay(cmap).apply(events_to_columns(events), 0, len(events))
    compiled_search.PathSearch(cmap.graph)(0, 1, 1.0)


class CompiledReplay:
    """Applies event columns to one map, compiled where it can (module doc).

    Keep one per map while replaying: it holds the map's edge table (which vertex pairs are
    joined), rebuilt when the map's Python code merged vertices since.
    """

    def __init__(self, cmap: CognitiveMap) -> None:
        """Replay into ``cmap`` (any state: new, or built part of the way).

        Raises:
            RuntimeError: the compiled replay is not available (:func:`available`).

        """
        if not available():
            raise RuntimeError(f"no compiled replay: {unavailable_reason()}")
        self.cmap = cmap
        self._table = np.full((0, 2), loop._EMPTY, dtype=np.int64)
        self._table_used = 0
        self._seen: tuple[int, int, int] | None = None  # graph counts when the table was made
        self._edge_log = np.empty((0, 3), dtype=np.int64)
        self._absorbed_log = np.empty((0, 2), dtype=np.int64)
        self._run_log = np.empty(0, dtype=np.int64)
        self._hist = np.empty((1, 3))
        #: events the map's Python code applied (the compiled loop stopped before them)
        self.escapes = 0
        self._search = compiled_search.PathSearch(cmap.graph)

    def apply(
        self,
        columns: Mapping[str, NDArray[Any]],
        lo: int,
        hi: int,
        after_python: Callable[[int], None] | None = None,
    ) -> None:
        """Apply events ``lo .. hi - 1`` of event columns to the map.

        The columns are those of :meth:`EventLog.columns <cogmap_core.event_log.EventLog.columns>`
        (``kind``, ``time``, ``ref``, ``view``, ``value0``, ``value1``). ``after_python(k)`` is
        called after the map's Python code applied event ``k`` (every cluster closes there).

        Raises:
            EventError: an event breaks the contract (raised by the map's Python code).

        """
        kind = np.ascontiguousarray(columns["kind"], dtype=np.uint8)
        time = np.ascontiguousarray(columns["time"], dtype=np.float64)
        ref = np.ascontiguousarray(columns["ref"], dtype=np.int64)
        view = np.ascontiguousarray(columns["view"], dtype=np.int64)
        value0 = np.ascontiguousarray(columns["value0"], dtype=np.float64)
        value1 = np.ascontiguousarray(columns["value1"], dtype=np.float64)
        k = lo
        while k < hi:
            k = self._run(kind, time, ref, view, value0, value1, k, hi)
            if k >= hi:
                break
            self.escapes += 1
            what = int(kind[k])
            t = float(time[k])
            event: Any
            if what == 0:
                event = Odometry(t, float(value0[k]), float(value1[k]))
            elif what == 1:
                event = CreateVertex(t, int(ref[k]), int(view[k]))
            elif what == 2:
                event = LinkToVertex(t, int(ref[k]), float(value0[k]))
            elif what == 3:
                event = SetCurrentVertex(t, int(ref[k]), float(value0[k]))
            else:
                raise ValueError(f"unknown event kind {what}")
            self._apply_python(event)
            if after_python is not None:
                after_python(k)
            k += 1

    def _apply_python(self, event: MapEvent) -> None:
        """The map's Python code applies ``event``, its gate searching paths compiled."""
        graph = self.cmap.graph
        if self._search.graph is not graph:
            self._search = compiled_search.PathSearch(graph)
        graph.path_search = self._search
        try:
            self.cmap.apply(event)
        finally:
            graph.path_search = None

    # ------------------------------------------------------------------ state in and out
    def _sync_table(self) -> None:
        """Bring the edge table up to date with the graph (rebuilt after merges)."""
        cmap = self.cmap
        g = cmap.graph
        # the graph's revision (every merge and every split of one changes it), edges removed
        revision = g.revision
        removed = g.num_edges_total - g.num_edges
        seen = self._seen
        need = 2 * (g.num_edges + 64)
        if seen is not None and seen[0] == revision and seen[1] == removed:
            if 2 * (self._table_used + g.num_edges_total - seen[2] + 64) <= self._table.shape[0]:
                for e in range(seen[2], g.num_edges_total):  # added by the Python code
                    self._table_used += loop._table_insert(
                        self._table, int(g.edge_from[e]), int(g.edge_to[e]), e
                    )
                self._seen = (revision, removed, g.num_edges_total)
                return
        size = 1024
        while size < 2 * need:
            size *= 2
        self._table = np.full((size, 2), loop._EMPTY, dtype=np.int64)
        self._table_used = loop._build_table(
            self._table, g.edge_from, g.edge_to, g.edge_alive, g.num_edges_total
        )
        self._seen = (revision, removed, g.num_edges_total)

    def _run(
        self,
        kind: NDArray[np.uint8],
        time: NDArray[np.float64],
        ref: NDArray[np.int64],
        view: NDArray[np.int64],
        value0: NDArray[np.float64],
        value1: NDArray[np.float64],
        lo: int,
        hi: int,
    ) -> int:
        """One compiled stretch from ``lo``; returns where it stopped."""
        cmap = self.cmap
        g = cmap.graph
        p = cmap.params
        self._sync_table()
        fs = np.zeros(F_SIZE)
        st = np.zeros(I_SIZE, dtype=np.int64)
        acc = cmap._accum
        fs[F_ACC0], fs[F_ACC1], fs[F_ACC2] = acc[0], acc[1], acc[2]
        fs[F_TRAVELLED] = cmap._travelled
        fs[F_LAST_ROTATION] = cmap._last_rotation
        fs[F_LAST_TIME] = cmap._last_time
        clusterer = cmap.clusterer
        cluster = clusterer.open_cluster
        if cluster is not None:
            fs[F_CLUSTER_START], fs[F_CLUSTER_LAST] = cluster.start_time, cluster.last_time
            st[I_CLUSTER_OPEN], st[I_CLUSTER_COUNT] = 1, cluster.edge_count
            st[I_CLUSTER_ID] = cluster.cluster_id
        fs[F_T_INTERVAL], fs[F_T_TOTAL] = clusterer.t_interval, clusterer.t_total
        fs[F_ALPHA], fs[F_BETA], fs[F_DELTA] = p.alpha, p.beta, p.delta
        fs[F_GATE_POSITION], fs[F_GATE_HEADING] = p.gate_position, p.gate_heading
        fs[F_GATE_DRIFT_POSITION] = p.gate_drift_position
        fs[F_GATE_DRIFT_HEADING] = p.gate_drift_heading
        fs[F_MIN_AGE] = p.integration_min_age
        st[I_CURRENT] = cmap._current
        link = cmap._last_link
        if link is not None:
            st[I_LINK], st[I_LINK_TARGET], st[I_LINK_ACCEPTED] = 1, link[1], int(link[2])
            fs[F_LINK_TIME] = link[0]
        st[I_STREAK] = len(cmap.gate.streak)
        st[I_NUM_IDS], st[I_NUM_VERTICES] = g.num_ids, g.num_vertices
        st[I_NUM_EDGES_TOTAL], st[I_NUM_EDGES] = g.num_edges_total, g.num_edges
        st[I_NUM_LOOP_EDGES] = g.num_loop_edges
        st[I_DECLINES], st[I_INTEGRATES] = int(cmap._declines), int(cmap._integrates)
        integration = cmap.integration
        st[I_RUN_OPEN] = int(integration.open is not None)
        at = integration._relocalised_at
        if at is not None:
            st[I_AT], st[I_AT_ROBOT], st[I_AT_END] = 1, at[0], at[1]
        st[I_TABLE_USED] = self._table_used
        n = hi - lo
        if self._run_log.shape[0] < n:  # the logs, kept from one stretch to the next
            size = max(n, 2 * self._run_log.shape[0])
            self._edge_log = np.empty((size, 3), dtype=np.int64)
            self._absorbed_log = np.empty((size, 2), dtype=np.int64)
            self._run_log = np.empty(size, dtype=np.int64)
            self._hist = np.empty((size + 1, 3))
        edge_log, absorbed_log = self._edge_log, self._absorbed_log
        run_log, hist = self._run_log, self._hist
        if cmap._hist_time:
            hist[0] = (cmap._hist_time[-1], cmap._hist_vertices[-1], cmap._hist_edges[-1])
            fs[F_HIST_TIME] = cmap._hist_time[-1]
            st[I_HIST_N] = 1
        stop = int(
            loop._replay(
                kind, time, ref, view, value0, value1, lo, hi, fs, st,
                g.pose, g.vertex_time, g.view, g.alive, g.alias, g.alias_offset,
                g.edge_from, g.edge_to, g.edge_rel, g.edge_time, g.edge_kind, g.edge_cluster,
                g.edge_alive, self._table, edge_log, absorbed_log, run_log, hist,
            )
        )  # fmt: skip
        # ---- back into the map's Python state
        cmap._accum = [float(fs[F_ACC0]), float(fs[F_ACC1]), float(fs[F_ACC2])]
        cmap._travelled = float(fs[F_TRAVELLED])
        cmap._last_rotation = float(fs[F_LAST_ROTATION])
        cmap._last_time = float(fs[F_LAST_TIME])
        if cluster is not None:
            cluster.last_time = float(fs[F_CLUSTER_LAST])
            cluster.edge_count = int(st[I_CLUSTER_COUNT])
        cmap._current = int(st[I_CURRENT])
        cmap._last_link = (
            (float(fs[F_LINK_TIME]), int(st[I_LINK_TARGET]), bool(st[I_LINK_ACCEPTED]))
            if st[I_LINK]
            else None
        )
        if st[I_STREAK] == 0 and cmap.gate.streak:
            cmap.gate.streak.clear()
        new_ids = int(st[I_NUM_IDS]) - g.num_ids
        g.adjacency.extend({} for _ in range(new_ids))
        g._absorbed.extend([] for _ in range(new_ids))
        g.num_ids = int(st[I_NUM_IDS])
        g.num_vertices = int(st[I_NUM_VERTICES])
        g.num_edges_total = int(st[I_NUM_EDGES_TOTAL])
        g.num_edges = int(st[I_NUM_EDGES])
        g.num_loop_edges = int(st[I_NUM_LOOP_EDGES])
        adjacency = g.adjacency
        for src, dst, e in edge_log[: st[I_N_EDGE_LOG]].tolist():
            adjacency[src][dst] = e
            adjacency[dst][src] = e
        absorbed = g._absorbed
        for target, vid in absorbed_log[: st[I_N_ABSORBED]].tolist():
            absorbed[target].append(vid)
        if st[I_N_RUN]:
            assert integration.open is not None
            integration.open.vertices.extend(run_log[: st[I_N_RUN]].tolist())
        integration._relocalised_at = (int(st[I_AT_ROBOT]), int(st[I_AT_END])) if st[I_AT] else None
        counters = cmap.counters
        counters.proposed += int(st[I_PROPOSED])
        counters.declined += int(st[I_DECLINED])
        counters.links += int(st[I_LINKS])
        counters.duplicate_links += int(st[I_DUPLICATES])
        self._table_used = int(st[I_TABLE_USED])
        if self._seen is not None:
            self._seen = (self._seen[0], self._seen[1], g.num_edges_total)
        count = int(st[I_HIST_N])
        if count:
            rows = hist[:count].tolist()
            start = 0
            if cmap._hist_time:
                start = 1
                if st[I_HIST_FIRST_CHANGED]:
                    cmap._hist_vertices[-1] = int(rows[0][1])
                    cmap._hist_edges[-1] = int(rows[0][2])
            for t, n_v, n_e in rows[start:]:
                cmap._hist_time.append(t)
                cmap._hist_vertices.append(int(n_v))
                cmap._hist_edges.append(int(n_e))
        return stop


def replay(cmap: CognitiveMap, columns: Mapping[str, NDArray[Any]], lo: int, hi: int) -> None:
    """Apply events ``lo .. hi - 1`` of event columns to ``cmap``, compiled when available.

    Without the compiled path, the same events go through
    :meth:`CognitiveMap.apply_all <cogmap_core.cognitive_map.CognitiveMap.apply_all>`.
    """
    if available():
        CompiledReplay(cmap).apply(columns, lo, hi)
        return
    cmap.apply_all(columns_to_events({name: columns[name][lo:hi] for name in _COLUMNS}))


_COLUMNS = ("kind", "time", "ref", "view", "value0", "value1")

__all__ = [
    "ENV_SWITCH",
    "CompiledReplay",
    "available",
    "replay",
    "unavailable_reason",
]
