"""The compiled replay's loop: the map's common decisions over plain arrays (numba-compilable).

Plain Python functions over numpy arrays that :func:`compile_all` compiles in place (each module
global is replaced by its compiled self, so the loop calls the compiled functions by their module
names): CPython's ``math.hypot``, the edge table (which vertex pairs are joined), the size history
and the loop :func:`_replay` itself, with the state vectors' indices (``F_*`` floats, ``I_*``
integers) :class:`~cogmap_core.compiled_replay.CompiledReplay` fills and reads back. The rules it
shares with the Python map are not copied: the clustering rule
(:func:`~cogmap_core.clustering.joins`), the angle wrap (:func:`~cogmap_core.geometry.wrap_scalar`)
and the relocalisation gate's excess (:func:`~cogmap_core.relocalisation.drift_excess`) are the
Python definitions, compiled here as this module's own. See :mod:`cogmap_core.compiled_replay`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.clustering import joins as _joins  # (compiled by compile_all, as its own)
from cogmap_core.geometry import TWO_PI
from cogmap_core.geometry import wrap_scalar as _wrap  # (the same)
from cogmap_core.relocalisation import drift_excess as _excess  # (the same)

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

    Plain Python, compiled by :func:`compile_all`; tested against ``math.hypot`` bit for bit.
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


_hypot = _python_hypot  # until compile_all() compiles it
#: The functions :func:`compile_all` compiles (each module global is replaced by its compiled self).
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


def compile_all(jit: Callable[[Any], Any]) -> None:
    """Compile the loop's functions with ``jit`` and put each in place of its Python self."""
    compiled = {name: jit(globals()[name]) for name in _COMPILED}
    compiled["_hypot"] = jit(_python_hypot)
    globals().update(compiled)  # the loop calls them by their module names


def uncompile() -> None:
    """Back to the Python functions (a failed compilation)."""
    global _hypot
    _hypot = _python_hypot
