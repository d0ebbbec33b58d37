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
import sys
import tempfile
from collections.abc import Callable, Mapping, MutableMapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.clustering import joins as _joins  # (compiled by _load, as its own)
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.event_file import columns_to_events, events_to_columns
from cogmap_core.events import (
    CreateVertex,
    LinkToVertex,
    MapEvent,
    Odometry,
    SetCurrentVertex,
)
from cogmap_core.geometry import TWO_PI
from cogmap_core.geometry import wrap_scalar as _wrap  # (compiled by _load, as its own)
from cogmap_core.relocalisation import drift_excess as _excess  # (the same)

#: Set to "0" to never use the compiled replay (e.g. to time the Python path).
ENV_SWITCH = "COGMAP_COMPILED_REPLAY"


def _writable(folder: Path) -> bool:
    """Whether files can be created in ``folder`` (made if missing)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".cogmap-probe-"):
            pass
    except OSError:
        return False
    return True


def choose_cache(
    source_dir: Path,
    env: MutableMapping[str, str],
    numba_imported: bool,
    home: Path,
    writable: Callable[[Path], bool] = _writable,
) -> bool:
    """Choose where numba caches compiled code (module doc); False: no cache at all.

    ``source_dir`` is numba's own choice (``__pycache__`` beside this file); ``env`` the
    environment, where ``NUMBA_CACHE_DIR`` is set to the user cache when that is the writable
    one -- numba reads it once, at import, so only while ``numba_imported`` is False. ``home``:
    the user's home folder (for ``~/.cache`` when ``XDG_CACHE_HOME`` is not set);
    ``writable``: whether a folder can be written (made when missing).
    """
    if env.get("NUMBA_CACHE_DIR"):
        return True
    if writable(source_dir):
        return True
    base = env.get("XDG_CACHE_HOME") or str(home / ".cache")
    user = Path(base) / "cogmap" / "numba"
    if not numba_imported and writable(user):
        env["NUMBA_CACHE_DIR"] = str(user)
        return True
    return False  # nowhere to write (or numba already set up otherwise): compile every time


_T27 = 134217729.0  # 2**27 + 1: Veltkamp's split of a double into two halves
_DBL_MIN = 2.2250738585072014e-308

# ---- the compiled loop's state vectors (indices) ----------------------------------------------
# floats
F_ACC0, F_ACC1, F_ACC2, F_TRAVELLED, F_LAST_ROTATION, F_LAST_TIME = 0, 1, 2, 3, 4, 5
F_CLUSTER_START, F_CLUSTER_LAST, F_LINK_TIME = 6, 7, 8
F_T_INTERVAL, F_T_TOTAL, F_ALPHA, F_BETA, F_DELTA = 9, 10, 11, 12, 13
F_GATE_POSITION, F_GATE_HEADING, F_GATE_DRIFT_POSITION, F_GATE_DRIFT_HEADING = 14, 15, 16, 17
F_MIN_AGE, F_HIST_TIME = 18, 19
F_SIZE = 20
# integers
I_CURRENT, I_CLUSTER_OPEN, I_CLUSTER_COUNT, I_CLUSTER_ID = 0, 1, 2, 3
I_LINK, I_LINK_TARGET, I_LINK_ACCEPTED, I_STREAK = 4, 5, 6, 7
I_NUM_IDS, I_NUM_VERTICES, I_NUM_EDGES_TOTAL, I_NUM_EDGES, I_NUM_LOOP_EDGES = 8, 9, 10, 11, 12
I_DECLINES, I_INTEGRATES, I_RUN_OPEN, I_AT, I_AT_ROBOT, I_AT_END = 13, 14, 15, 16, 17, 18
I_PROPOSED, I_DECLINED, I_LINKS, I_DUPLICATES = 19, 20, 21, 22
I_TABLE_USED, I_N_EDGE_LOG, I_N_ABSORBED, I_N_RUN = 23, 24, 25, 26
I_HIST, I_HIST_V, I_HIST_E, I_HIST_N, I_HIST_FIRST_CHANGED = 27, 28, 29, 30, 31
I_SIZE = 32

_EMPTY = -1  # a free slot of the edge table


def _python_hypot(x: float, y: float) -> float:
    """CPython 3.11's ``math.hypot`` of two values (``vector_norm``), step by step.

    Plain Python, compiled by :func:`_load`; tested against ``math.hypot`` bit for bit.
    """
    ax, ay = abs(x), abs(y)
    if math.isnan(ax) or math.isnan(ay):
        return math.inf if math.isinf(ax) or math.isinf(ay) else math.nan
    mx = ax if ax > ay else ay
    if math.isinf(mx) or mx == 0.0:
        return mx
    factor = 1.0
    _, e = math.frexp(mx)
    if e < -1023:  # subnormal: scaled up and the result back down, as CPython does
        ax, ay, mx, factor = ax / _DBL_MIN, ay / _DBL_MIN, mx / _DBL_MIN, _DBL_MIN
        _, e = math.frexp(mx)
    scale = math.ldexp(1.0, -e)
    csum, frac1, frac2, frac3 = 1.0, 0.0, 0.0, 0.0
    for x0 in (ax, ay):
        v = x0 * scale
        t = v * _T27
        hi = t - (t - v)
        lo = v - hi
        v = hi * hi
        old = csum
        csum += v
        frac1 += (old - csum) + v
        v = 2.0 * hi * lo
        old = csum
        csum += v
        frac2 += (old - csum) + v
        frac3 += lo * lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    t = h * _T27
    hi = t - (t - h)
    lo = h - hi
    v = -hi * hi
    old = csum
    csum += v
    frac1 += (old - csum) + v
    v = -2.0 * hi * lo
    old = csum
    csum += v
    frac2 += (old - csum) + v
    v = -lo * lo
    old = csum
    csum += v
    frac3 += (old - csum) + v
    v = csum - 1.0 + (frac1 + frac2 + frac3)
    return factor * ((h + v / (2.0 * h)) / scale)


def _pair_key(a: int, b: int) -> int:
    """One key for the unordered vertex pair ``{a, b}``."""
    return (a << 32) | b if a < b else (b << 32) | a


def _slot(table: NDArray[np.int64], key: int) -> int:
    """The slot of ``key`` in the edge table, or the free slot where it would go."""
    mask = table.shape[0] - 1
    i = ((key * 0x9E3779B1) >> 7) & mask
    while True:
        k = table[i, 0]
        if k == key or k == _EMPTY:
            return int(i)
        i = (i + 1) & mask


def _table_insert(table: NDArray[np.int64], a: int, b: int, edge: int) -> int:
    """Record that edge ``edge`` joins ``a`` and ``b``; 1 when the pair is new, else 0."""
    key = _pair_key(a, b)
    i = _slot(table, key)
    fresh = 1 if table[i, 0] == _EMPTY else 0
    table[i, 0] = key
    table[i, 1] = edge
    return fresh


def _build_table(
    table: NDArray[np.int64],
    edge_from: NDArray[np.int64],
    edge_to: NDArray[np.int64],
    edge_alive: NDArray[np.bool_],
    count: int,
) -> int:
    """Fill an empty edge table with the live edges among the first ``count``; return its load."""
    used = 0
    for k in range(count):
        if edge_alive[k]:
            used += _table_insert(table, edge_from[k], edge_to[k], k)
    return used


def _edge_between(table: NDArray[np.int64], a: int, b: int) -> int:
    """The live edge joining ``a`` and ``b``, or -1 (:meth:`MapGraph.edge_between`)."""
    key = _pair_key(a, b)
    i = _slot(table, key)
    return int(table[i, 1]) if table[i, 0] == key else -1


def _record_size(fs: NDArray[np.float64], st: NDArray[np.int64], t: float, hist: Any) -> None:
    """``CognitiveMap._record_size``: entry 0 of ``hist`` is the map's last one (if any)."""
    n_v, n_e = st[I_NUM_VERTICES], st[I_NUM_EDGES]
    n = st[I_HIST_N]
    if n > 0 and hist[n - 1, 1] == n_v and hist[n - 1, 2] == n_e:
        return
    if n > 0 and fs[F_HIST_TIME] == t:
        hist[n - 1, 1] = n_v
        hist[n - 1, 2] = n_e
        if n == 1:
            st[I_HIST_FIRST_CHANGED] = 1
        return
    hist[n, 0] = t
    hist[n, 1] = n_v
    hist[n, 2] = n_e
    fs[F_HIST_TIME] = t
    st[I_HIST_N] = n + 1


def _replay(
    kind: NDArray[np.uint8],
    time: NDArray[np.float64],
    ref: NDArray[np.int64],
    view: NDArray[np.int64],
    value0: NDArray[np.float64],
    value1: NDArray[np.float64],
    lo: int,
    hi: int,
    fs: NDArray[np.float64],
    st: NDArray[np.int64],
    pose: NDArray[np.float64],
    vertex_time: NDArray[np.float64],
    vertex_view: NDArray[np.int64],
    alive: NDArray[np.bool_],
    alias: NDArray[np.int64],
    alias_offset: NDArray[np.float64],
    edge_from: NDArray[np.int64],
    edge_to: NDArray[np.int64],
    edge_rel: NDArray[np.float64],
    edge_time: NDArray[np.float64],
    edge_kind: NDArray[np.int8],
    edge_cluster: NDArray[np.int64],
    edge_alive: NDArray[np.bool_],
    table: NDArray[np.int64],
    edge_log: NDArray[np.int64],
    absorbed_log: NDArray[np.int64],
    run_log: NDArray[np.int64],
    hist: NDArray[np.float64],
) -> int:
    """Apply events ``lo .. hi - 1`` until one the Python code must apply; return its index."""
    pi = math.pi
    vcap = pose.shape[0]
    ecap = edge_from.shape[0]
    tcap = table.shape[0]
    for k in range(lo, hi):
        t = time[k]
        if not (t >= fs[F_LAST_TIME] and t != math.inf):
            return k  # the contract error is raised by the Python code
        if st[I_CLUSTER_OPEN] == 1 and not _joins(
            fs[F_CLUSTER_START], fs[F_CLUSTER_LAST], t, fs[F_T_INTERVAL], fs[F_T_TOTAL]
        ):
            return k  # the cluster closes: optimisation
        what = kind[k]
        current = st[I_CURRENT]
        if what == 0:  # odometry
            trans, rot = value0[k], value1[k]
            if not (math.isfinite(trans) and math.isfinite(rot)):
                return k
            fs[F_LAST_TIME] = t
            heading = (fs[F_ACC2] + rot + pi) % TWO_PI - pi
            fs[F_ACC2] = heading
            fs[F_ACC0] += trans * math.cos(heading)
            fs[F_ACC1] += trans * math.sin(heading)
            fs[F_TRAVELLED] += abs(trans)
            fs[F_LAST_ROTATION] = rot
            continue
        if what == 1:  # create vertex
            vid = ref[k]
            if vid != st[I_NUM_IDS] or vid + 1 > vcap:
                return k
            r0, r1, r2 = fs[F_ACC0], fs[F_ACC1], fs[F_ACC2]
            decline = False
            if current >= 0:
                if st[I_DECLINES] == 1:
                    d = _hypot(r0, r1)
                    g = (1.0 + fs[F_ALPHA] * d) * (1.0 + fs[F_BETA] * abs(r2))
                    decline = not g > fs[F_DELTA]
                if not decline:
                    if st[I_NUM_EDGES_TOTAL] + 1 > ecap or 2 * (st[I_TABLE_USED] + 1) > tcap:
                        return k
                    if st[I_INTEGRATES] == 1 and st[I_RUN_OPEN] == 0:
                        return k  # a revisit run opens (a Python object)
            fs[F_LAST_TIME] = t
            st[I_NUM_IDS] = vid + 1
            vertex_time[vid] = t
            vertex_view[vid] = view[k]
            st[I_PROPOSED] += 1
            if current < 0:  # the map's first vertex
                pose[vid, 0], pose[vid, 1], pose[vid, 2] = r0, r1, _wrap(r2)
                alive[vid] = True
                alias[vid] = vid
                alias_offset[vid, 0] = alias_offset[vid, 1] = alias_offset[vid, 2] = 0.0
                st[I_NUM_VERTICES] += 1
                st[I_CURRENT] = vid
                fs[F_ACC0], fs[F_ACC1], fs[F_ACC2] = 0.0, 0.0, _wrap(0.0)
                fs[F_TRAVELLED] = 0.0
            elif decline:  # not novel: an alias of the current vertex
                alias[vid] = current
                alias_offset[vid, 0], alias_offset[vid, 1], alias_offset[vid, 2] = r0, r1, r2
                n = st[I_N_ABSORBED]
                absorbed_log[n, 0], absorbed_log[n, 1] = current, vid
                st[I_N_ABSORBED] = n + 1
                st[I_DECLINED] += 1
            else:
                c, s = math.cos(pose[current, 2]), math.sin(pose[current, 2])
                p0 = pose[current, 0] + c * r0 - s * r1
                p1 = pose[current, 1] + s * r0 + c * r1
                p2 = (pose[current, 2] + r2 + pi) % TWO_PI - pi
                pose[vid, 0], pose[vid, 1], pose[vid, 2] = p0, p1, _wrap(p2)
                alive[vid] = True
                alias[vid] = vid
                alias_offset[vid, 0] = alias_offset[vid, 1] = alias_offset[vid, 2] = 0.0
                st[I_NUM_VERTICES] += 1
                e = st[I_NUM_EDGES_TOTAL]
                edge_from[e], edge_to[e] = current, vid
                edge_rel[e, 0], edge_rel[e, 1], edge_rel[e, 2] = r0, r1, _wrap(r2)
                edge_time[e] = t
                edge_kind[e] = 0
                edge_cluster[e] = -1
                edge_alive[e] = True
                st[I_TABLE_USED] += _table_insert(table, current, vid, e)
                n = st[I_N_EDGE_LOG]
                edge_log[n, 0], edge_log[n, 1], edge_log[n, 2] = current, vid, e
                st[I_N_EDGE_LOG] = n + 1
                st[I_NUM_EDGES_TOTAL] = e + 1
                st[I_NUM_EDGES] += 1
                if st[I_INTEGRATES] == 1:
                    st[I_AT] = 0
                    run_log[st[I_N_RUN]] = vid
                    st[I_N_RUN] += 1
                st[I_CURRENT] = vid
                fs[F_ACC0], fs[F_ACC1], fs[F_ACC2] = 0.0, 0.0, _wrap(0.0)
                fs[F_TRAVELLED] = 0.0
            _record_size(fs, st, t, hist)
            continue
        if what == 2 or what == 3:
            raw = ref[k]
            rel = value0[k]
            if raw < 0 or raw >= st[I_NUM_IDS] or not math.isfinite(rel):
                return k
            target = alias[raw]
            o0, o1, o2 = alias_offset[raw, 0], alias_offset[raw, 1], alias_offset[raw, 2]
            if what == 3:  # set current
                link_matches = st[I_LINK] == 1 and fs[F_LINK_TIME] == t and st[I_LINK_TARGET] == raw
                if not link_matches and current >= 0:
                    return k  # a relocalisation without its link: tested by the Python code
                fs[F_LAST_TIME] = t
                st[I_LINK] = 0
                if not (link_matches and st[I_LINK_ACCEPTED] == 0):
                    st[I_CURRENT] = target
                    fs[F_ACC0], fs[F_ACC1], fs[F_ACC2] = o0, o1, _wrap(o2 + rel)
                    fs[F_TRAVELLED] = 0.0
                _record_size(fs, st, t, hist)
                continue
            # link
            if current < 0 or st[I_CLUSTER_OPEN] == 0:
                return k  # an error, or a new cluster (a Python object)
            a0, a1, a2 = fs[F_ACC0], fs[F_ACC1], fs[F_ACC2]
            # the relocalisation test (relocalisation.check_relocalisation)
            c, s = math.cos(pose[current, 2]), math.sin(pose[current, 2])
            q0 = pose[current, 0] + c * a0 - s * a1
            q1 = pose[current, 1] + s * a0 + c * a1
            q2 = (pose[current, 2] + a2 + pi) % TWO_PI - pi
            c, s = math.cos(pose[target, 2]), math.sin(pose[target, 2])
            w0 = pose[target, 0] + c * o0 - s * o1
            w1 = pose[target, 1] + s * o0 + c * o1
            w2 = (pose[target, 2] + o2 + pi) % TWO_PI - pi
            position_error = _hypot(q0 - w0, q1 - w1)
            heading_error = abs(_wrap(q2 - (w2 + rel)))
            heading_tolerance = fs[F_GATE_HEADING] + abs(fs[F_LAST_ROTATION])
            excess_p = _excess(position_error, fs[F_GATE_POSITION], fs[F_GATE_DRIFT_POSITION])
            excess_h = _excess(heading_error, heading_tolerance, fs[F_GATE_DRIFT_HEADING])
            excess = excess_h if excess_h > excess_p else excess_p  # Python's max()
            if not excess <= 0.0:
                needed = excess - fs[F_TRAVELLED] - _hypot(o0, o1)
                if not needed <= 0.0:
                    return k  # a path search, or refused: the Python code decides
            duplicate = target == current or _edge_between(table, current, target) >= 0
            if not duplicate and (
                st[I_NUM_EDGES_TOTAL] + 1 > ecap or 2 * (st[I_TABLE_USED] + 1) > tcap
            ):
                return k
            closes_run = (
                st[I_INTEGRATES] == 1
                and not t - vertex_time[raw] < fs[F_MIN_AGE]
                and st[I_RUN_OPEN] == 1
            )
            if closes_run:
                return k  # a revisit run closes: scene integration judges it
            # accepted
            fs[F_LAST_TIME] = t
            st[I_LINKS] += 1
            fs[F_CLUSTER_LAST] = t
            st[I_CLUSTER_COUNT] += 1
            st[I_STREAK] = 0
            st[I_LINK], st[I_LINK_TARGET], st[I_LINK_ACCEPTED] = 1, raw, 1
            fs[F_LINK_TIME] = t
            p0, p1, p2 = a0, a1, a2 - rel  # the robot at the place it recognised
            if duplicate:
                st[I_DUPLICATES] += 1
            else:
                # compose(to_place, inverse(offset))
                c, s = math.cos(o2), math.sin(o2)
                i0 = -(c * o0 + s * o1)
                i1 = s * o0 - c * o1
                i2 = (pi - o2) % TWO_PI - pi
                c, s = math.cos(p2), math.sin(p2)
                e0 = p0 + c * i0 - s * i1
                e1 = p1 + s * i0 + c * i1
                e2 = (p2 + i2 + pi) % TWO_PI - pi
                e = st[I_NUM_EDGES_TOTAL]
                edge_from[e], edge_to[e] = current, target
                edge_rel[e, 0], edge_rel[e, 1], edge_rel[e, 2] = e0, e1, _wrap(e2)
                edge_time[e] = t
                edge_kind[e] = 1
                edge_cluster[e] = st[I_CLUSTER_ID]
                edge_alive[e] = True
                st[I_TABLE_USED] += _table_insert(table, current, target, e)
                n = st[I_N_EDGE_LOG]
                edge_log[n, 0], edge_log[n, 1], edge_log[n, 2] = current, target, e
                st[I_N_EDGE_LOG] = n + 1
                st[I_NUM_EDGES_TOTAL] = e + 1
                st[I_NUM_EDGES] += 1
                st[I_NUM_LOOP_EDGES] += 1
            if st[I_INTEGRATES] == 1 and not t - vertex_time[raw] < fs[F_MIN_AGE]:
                st[I_AT], st[I_AT_ROBOT], st[I_AT_END] = 1, current, raw
            _record_size(fs, st, t, hist)
            continue
        return k  # an unknown kind: the Python code raises
    return hi


def _check(xs: NDArray[np.float64]) -> NDArray[np.float64]:
    """hypot, wrap, cos and sin of sample pairs (to compare with CPython's)."""
    out = np.empty((xs.shape[0], 4))
    for i in range(xs.shape[0]):
        out[i, 0] = _hypot(xs[i, 0], xs[i, 1])
        out[i, 1] = _wrap(xs[i, 0] + xs[i, 1])
        out[i, 2] = math.cos(xs[i, 0])
        out[i, 3] = math.sin(xs[i, 1])
    return out


_hypot = _python_hypot  # until _load() compiles it
#: The functions compiled by :func:`_load` (each module global is replaced by its compiled self).
_COMPILED = (
    "_wrap",
    "_joins",
    "_pair_key",
    "_slot",
    "_table_insert",
    "_build_table",
    "_edge_between",
    "_excess",
    "_record_size",
    "_replay",
    "_check",
)
_AVAILABLE: bool | None = None
_REASON: str | None = None


def _load() -> None:
    """Import numba, compile the loop (or load it from the cache) and check it (once)."""
    global _AVAILABLE, _REASON, _hypot
    _AVAILABLE = False
    cache = choose_cache(
        Path(__file__).resolve().parent / "__pycache__",
        os.environ,
        "numba" in sys.modules,
        Path(os.path.expanduser("~")),
    )
    try:
        import numba
    except ImportError:
        _REASON = "numba is not installed"
        return
    try:
        jit = numba.njit(cache=cache)
        compiled = {name: jit(globals()[name]) for name in _COMPILED}
        compiled["_hypot"] = jit(_python_hypot)
        globals().update(compiled)  # the loop calls them by their module names
        _AVAILABLE = _self_check()
        if not _AVAILABLE:
            _REASON = "compiled arithmetic differs from CPython's"
        else:
            _warm_up()
    except Exception as exc:  # a broken numba or LLVM: the Python path still works
        _AVAILABLE = False
        _REASON = f"{type(exc).__name__}: {exc}"
        _hypot = _python_hypot


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
    got = _check(xs)
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
    """Run the compiled loop once on a few events, so that a first rebuild does not compile it."""
    events: list[MapEvent] = [
        Odometry(0.1, 0.1, 0.0),
        CreateVertex(0.1, 0, 0),
        Odometry(0.2, 0.1, 0.1),
        CreateVertex(0.2, 1, 1),
        LinkToVertex(0.3, 0, 0.0),
        SetCurrentVertex(0.3, 0, 0.0),
    ]
    CompiledReplay(CognitiveMap(MapMode.COMPACT)).apply(events_to_columns(events), 0, len(events))


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
        self._table = np.full((0, 2), _EMPTY, dtype=np.int64)
        self._table_used = 0
        self._seen: tuple[int, int, int] | None = None  # graph counts when the table was made
        self._edge_log = np.empty((0, 3), dtype=np.int64)
        self._absorbed_log = np.empty((0, 2), dtype=np.int64)
        self._run_log = np.empty(0, dtype=np.int64)
        self._hist = np.empty((1, 3))
        #: events the map's Python code applied (the compiled loop stopped before them)
        self.escapes = 0

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
            self.cmap.apply(event)
            if after_python is not None:
                after_python(k)
            k += 1

    # ------------------------------------------------------------------ state in and out
    def _sync_table(self) -> None:
        """Bring the edge table up to date with the graph (rebuilt after merges)."""
        cmap = self.cmap
        g = cmap.graph
        merged = g.num_ids - g.num_vertices - cmap.counters.declined  # vertices merged away
        removed = g.num_edges_total - g.num_edges
        seen = self._seen
        need = 2 * (g.num_edges + 64)
        if seen is not None and seen[0] == merged and seen[1] == removed:
            if 2 * (self._table_used + g.num_edges_total - seen[2] + 64) <= self._table.shape[0]:
                for e in range(seen[2], g.num_edges_total):  # added by the Python code
                    self._table_used += _table_insert(
                        self._table, int(g.edge_from[e]), int(g.edge_to[e]), e
                    )
                self._seen = (merged, removed, g.num_edges_total)
                return
        size = 1024
        while size < 2 * need:
            size *= 2
        self._table = np.full((size, 2), _EMPTY, dtype=np.int64)
        self._table_used = _build_table(
            self._table, g.edge_from, g.edge_to, g.edge_alive, g.num_edges_total
        )
        self._seen = (merged, removed, g.num_edges_total)

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
            _replay(
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
    "choose_cache",
    "replay",
    "unavailable_reason",
]
