"""Compiled (numba) loops of the front end, computing exactly what its numpy code computes.

The view-template search (:func:`match_pairs`) replaces a dozen small numpy operations per frame
by one loop over the same pruning cascade (module doc of
:mod:`cogmap_core.frontend.local_view`): its numbers are exact integers (block sums, bounds and
sums of absolute differences), so it finds the same pair, with the same count of exact
comparisons. :func:`block_sums` adds up OpenRatSLAM's template blocks in integers (what the
integral image gives exactly). :func:`decode_peak` is the pose cells' peak decoding with the
same sums in the same order (sequential double additions, ``atan2`` of the C library as CPython
uses it).

numba is optional: without it, when compiling fails, with ``COGMAP_COMPILED_FRONTEND=0``, or
in a program that prefers the numpy code (:func:`prefer_compiled`), :func:`kernels` returns
None and the front end runs its numpy code (the same results). Compiled code is cached on disk
where :func:`cogmap_core.numba_cache.choose_cache` says.
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace
from typing import Any

import numpy as np

#: Set to "0" to run the front end's numpy code instead (e.g. to time or check it).
ENV_SWITCH = "COGMAP_COMPILED_FRONTEND"

_KERNELS: SimpleNamespace | None = None
_LOADED = False
#: Whether :func:`kernels` gives the compiled loops when :data:`ENV_SWITCH` is unset
#: (:func:`prefer_compiled`).
_PREFERRED = True


def _block_sums(flat: Any, depth: int, rows: Any, cols: Any, out: Any) -> None:
    """``out[i, j]``: sum of the pixels ``rows[i]:rows[i+1]``, ``cols[j]:cols[j+1]`` (int64).

    ``flat``: the image as ``(h, w * depth)``; a colour image (``depth`` 3) adds blue, green
    and red.
    """
    first, last = cols[0] * depth, cols[-1] * depth
    column = np.empty(last - first, dtype=np.int64)
    for i in range(len(rows) - 1):
        column[:] = 0
        for r in range(rows[i], rows[i + 1]):
            line = flat[r]
            for c in range(first, last):
                column[c - first] += line[c]
        for j in range(len(cols) - 1):
            s = 0
            for c in range(cols[j] * depth - first, cols[j + 1] * depth - first):
                s += column[c]
            out[i, j] = s


def _window_blocks(view: Any, first: int, rows: Any, cols: Any, out: Any) -> None:
    """Block sums of ``view[:, first:]`` as a flat ``out`` (row blocks, then column blocks)."""
    n_cols = len(cols) - 1
    for i in range(len(rows) - 1):
        for j in range(n_cols):
            s = 0
            for r in range(rows[i], rows[i + 1]):
                for c in range(cols[j], cols[j + 1]):
                    s += view[r, first + c]
            out[i * n_cols + j] = s


def _pair_sad(templates: Any, t: int, o: int, view: Any, shift: int, width: int) -> int:
    """Sum of absolute differences of template ``t`` at column ``o`` and the view's centre."""
    s = 0
    for r in range(view.shape[0]):
        for c in range(width):
            d = np.int64(templates[t, r, o + c]) - np.int64(view[r, shift + c])
            s += d if d >= 0 else -d
    return s


def _within(desc: Any, row: int, v: Any, bound: float) -> bool:
    """Whether ``sum |desc[row] - v| <= bound`` (exact: integers in floating point)."""
    s = 0.0
    for k in range(len(v)):
        d = desc[row, k] - v[k]
        s += d if d >= 0 else -d
        if s > bound:
            return False
    return True


def _match_pairs(
    view: Any,
    templates: Any,
    count: int,
    shift: int,
    width: int,
    offsets: Any,
    sums: Any,
    mean_skip: bool,
    mean_limit: float,
    hint: int,
    max_sad: int,
    blocks1: Any,
    blocks2: Any,
    signs: Any,
    keys: Any,
    ids: Any,
    sorted1: Any,
    indexed: int,
    keys_all: Any,
    desc1: Any,
    desc2: Any,
    level2_min: int,
) -> Any:
    """The pruned exact search of ``LocalViewCells.match``.

    Returns ``(template, offset index, sad, evaluated)``, template -1 when nothing is within the
    threshold. ``blocks1`` / ``blocks2``: (row edges, column edges) of the level-1 and level-2
    blocks of the compared window; ``sorted1``: the indexed pairs' level-1 descriptors
    ``(k1, pairs)``.
    """
    n_off = len(offsets)
    total = np.int64(0)
    for r in range(view.shape[0]):
        for c in range(view.shape[1]):
            total += view[r, c]
    allowed = np.ones(count, dtype=np.bool_)
    if mean_skip:
        for t in range(count):
            allowed[t] = abs(sums[t] - total) <= mean_limit
    bound = max_sad
    evaluated = 0
    if 0 <= hint < count and allowed[hint]:
        for o in range(n_off):
            s = _pair_sad(templates, hint, offsets[o], view, shift, width)
            evaluated += 1
            if s < bound:
                bound = s
    rows1, cols1 = blocks1
    k1 = (len(rows1) - 1) * (len(cols1) - 1)
    v1 = np.empty(k1, dtype=desc1.dtype)
    _window_blocks(view, shift, rows1, cols1, v1)
    v0 = np.int64(0)
    for k in range(k1):
        v0 += np.int64(v1[k]) * np.int64(signs[k])
    found = np.empty(count * n_off, dtype=np.int64)
    n_found = 0
    fbound = float(bound)
    if indexed > 0:
        lo = np.searchsorted(keys, v0 - bound)
        hi = np.searchsorted(keys, v0 + bound + 1)
        for j in range(lo, hi):
            s = 0.0
            for k in range(k1):
                d = sorted1[k, j] - v1[k]
                s += d if d >= 0 else -d
            if s <= fbound:
                found[n_found] = ids[j]
                n_found += 1
    for flat in range(indexed * n_off, count * n_off):
        key = keys_all[flat // n_off, flat % n_off]
        if abs(key - v0) <= bound and _within(desc1, flat, v1, fbound):
            found[n_found] = flat
            n_found += 1
    if n_found == 0:
        return -1, -1, -1, evaluated
    kept = 0
    for i in range(n_found):
        if allowed[found[i] // n_off]:
            found[kept] = found[i]
            kept += 1
    n_found = kept
    if n_found > level2_min:
        rows2, cols2 = blocks2
        v2 = np.empty((len(rows2) - 1) * (len(cols2) - 1), dtype=desc2.dtype)
        _window_blocks(view, shift, rows2, cols2, v2)
        kept = 0
        for i in range(n_found):
            if _within(desc2, found[i], v2, fbound):
                found[kept] = found[i]
                kept += 1
        n_found = kept
    if n_found == 0:
        return -1, -1, -1, evaluated
    best_sad = np.int64(-1)
    best = np.int64(-1)
    for i in range(n_found):
        flat = found[i]
        s = _pair_sad(templates, flat // n_off, offsets[flat % n_off], view, shift, width)
        if best_sad < 0 or s < best_sad or (s == best_sad and flat < best):
            best_sad, best = s, flat
    evaluated += n_found
    if best_sad > max_sad:
        return -1, -1, -1, evaluated
    return best // n_off, best % n_off, best_sad, evaluated


def _decode_axis(sums: Any, cells: Any, sincos: Any, dim: int) -> float:
    """``_ors_decode`` of :mod:`cogmap_core.frontend.pose_cells`: cells in index order."""
    order = np.argsort(cells)
    s = 0.0
    c = 0.0
    for m in range(len(order)):
        cell = cells[order[m]]
        total = sums[order[m]]
        s += sincos[cell, 0] * total
        c += sincos[cell, 1] * total
    value = math.atan2(s, c) * dim / (2.0 * math.pi) - 1.0
    while value < 0:
        value += dim
    while value > dim:
        value -= dim
    return value


def _decode_peak(p: Any, reach: int, sincos_xy: Any, sincos_th: Any) -> Any:
    """``PoseCellNetwork.find_best``: the same per-axis sums, added in the same order."""
    n_th, n_y, n_x = p.shape
    best = 0
    flat = p.ravel()
    for m in range(1, flat.size):
        if flat[m] > flat[best]:
            best = m
    k = best // (n_y * n_x)
    j = (best // n_x) % n_y
    i = best % n_x
    w = 2 * reach + 1
    ith = np.empty(w, dtype=np.int64)
    iy = np.empty(w, dtype=np.int64)
    ix = np.empty(w, dtype=np.int64)
    for m in range(w):
        ith[m] = (k + m - reach) % n_th
        iy[m] = (j + m - reach) % n_y
        ix[m] = (i + m - reach) % n_x
    x_sums = np.empty(w)
    y_sums = np.empty(w)
    z_sums = np.empty(w)
    # numpy's reductions over a leading axis: the first term, then the others in order
    for c in range(w):
        first = True
        for a in range(w):
            for b in range(w):
                v = p[ith[a], iy[b], ix[c]]
                x_sums[c] = v if first else x_sums[c] + v
                first = False
    for b in range(w):
        first = True
        for a in range(w):
            for c in range(w):
                v = p[ith[a], iy[b], ix[c]]
                y_sums[b] = v if first else y_sums[b] + v
                first = False
    for a in range(w):
        first = True
        for b in range(w):
            for c in range(w):
                v = p[ith[a], iy[b], ix[c]]
                z_sums[a] = v if first else z_sums[a] + v
                first = False
    x = _decode_axis(x_sums, ix, sincos_xy, n_x)
    y = _decode_axis(y_sums, iy, sincos_xy, n_y)
    th = _decode_axis(z_sums, ith, sincos_th, n_th)
    return x, y, th


_COMPILED = (
    "_decode_axis",
    "_block_sums",
    "_window_blocks",
    "_pair_sad",
    "_within",
)


def prefer_compiled(compiled: bool) -> None:
    """Whether front ends made from now on use the compiled loops when the switch is unset.

    ``COGMAP_COMPILED_FRONTEND`` decides when it is set (``0`` never, anything else always).
    Unset, the loops are used unless a program preferred the numpy code: ``cogmap run`` does,
    since loading numba and LLVM for them raises its peak memory by ~100 MB for a ~1.1x shorter
    run, while the web app and sweeps load numba for their compiled map replay anyway.
    """
    global _PREFERRED
    _PREFERRED = compiled


def kernels() -> SimpleNamespace | None:
    """The compiled loops (``match_pairs``, ``block_sums``, ``decode_peak``), or None.

    Compiled (or loaded from the cache) on the first call; None when numba is missing, fails,
    when ``COGMAP_COMPILED_FRONTEND=0``, or when the switch is unset and the program preferred
    the numpy code (:func:`prefer_compiled`).
    """
    global _KERNELS, _LOADED
    switch = os.environ.get(ENV_SWITCH)
    if switch == "0" or (switch is None and not _PREFERRED):
        return None
    if not _LOADED:
        _LOADED = True
        _KERNELS = _load()
    return _KERNELS


def _load() -> SimpleNamespace | None:
    from cogmap_core.numba_cache import cached_njit

    try:
        jit = cached_njit(__file__)
        compiled = {name: jit(globals()[name]) for name in _COMPILED}
        globals().update(compiled)  # the loops call each other by their module names
        match = jit(_match_pairs)
        decode = jit(_decode_peak)
    except Exception:  # no numba, or a broken one: the numpy code gives the same results
        return None
    return SimpleNamespace(
        match_pairs=match,
        block_sums=compiled["_block_sums"],
        decode_peak=decode,
    )
