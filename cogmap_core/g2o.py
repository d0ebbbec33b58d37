"""Read and write 2D pose graphs: g2o (``VERTEX_SE2``/``EDGE_SE2``), TORO (``VERTEX2``/``EDGE2``).

g2o stores the upper triangle of each edge's information matrix as ``I11 I12 I13 I22 I23 I33``;
TORO stores ``Ixx Ixy Iyy Itt Ixt Iyt``. ``FIX id`` lines mark fixed vertices. Comments start
with ``#``. Every malformed input raises :class:`G2oFormatError` naming the file and line.

A file with edges but no vertex lines (as SE-Sync and many benchmark sets ship them) gets one
vertex per id named by the edges, in id order, with poses chained along the edges from the
first vertex of each connected part (:func:`chained_poses`).
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import G2oFormatError, InputFileError
from cogmap_core.fileio import atomic_writer
from cogmap_core.geometry import compose_scalar, inverse_scalar
from cogmap_core.posegraph import PoseGraph

_VERTEX_TAGS = {"VERTEX_SE2": "g2o", "VERTEX2": "toro"}
_EDGE_TAGS = {"EDGE_SE2": "g2o", "EDGE2": "toro"}
_IGNORED_TAGS = {"PARAMS_SE2OFFSET"}


def _numbers(path: Path, lineno: int, tag: str, tokens: list[str], count: int) -> list[float]:
    if len(tokens) != count:
        raise G2oFormatError(
            f"{path}:{lineno}: {tag} needs {count} values after the tag, found {len(tokens)}; "
            "fix or remove the line"
        )
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise G2oFormatError(
            f"{path}:{lineno}: {tag} has a value that is not a number ({' '.join(tokens)}); "
            "fix or remove the line"
        ) from None
    if not all(math.isfinite(v) for v in values):
        raise G2oFormatError(
            f"{path}:{lineno}: {tag} has a NaN or infinite value; fix or remove the line"
        )
    return values


_ID_MIN, _ID_MAX = -(2**63), 2**63 - 1


def _vertex_id(path: Path, lineno: int, tag: str, token: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise G2oFormatError(
            f"{path}:{lineno}: {tag} vertex id {token!r} is not an integer; fix the line"
        ) from None
    if not _ID_MIN <= value <= _ID_MAX:
        raise G2oFormatError(
            f"{path}:{lineno}: {tag} vertex id {token} is out of range (-2^63 to 2^63-1); "
            "renumber the vertices"
        )
    return value


def chained_poses(
    edge_from: NDArray[np.int64],
    edge_to: NDArray[np.int64],
    measurements: NDArray[np.float64],
    n: int,
) -> NDArray[np.float64]:
    """Poses of ``n`` vertices chained along the edges (odometry), breadth first.

    The first vertex of each connected part sits at the origin; every other vertex is placed
    from the first edge (in file order) that reaches it, composing its measurement (or its
    inverse when the edge is walked backwards).
    """
    adjacency: list[list[tuple[int, int, bool]]] = [[] for _ in range(n)]
    for k, (i, j) in enumerate(zip(edge_from.tolist(), edge_to.tolist(), strict=True)):
        adjacency[i].append((j, k, True))
        adjacency[j].append((i, k, False))
    poses = [(0.0, 0.0, 0.0)] * n
    placed = [False] * n
    meas = measurements.tolist()
    for root in range(n):
        if placed[root]:
            continue
        placed[root] = True
        queue = deque([root])
        while queue:
            u = queue.popleft()
            for v, k, forward in adjacency[u]:
                if placed[v]:
                    continue
                step = meas[k] if forward else inverse_scalar(meas[k])
                poses[v] = compose_scalar(poses[u], step)
                placed[v] = True
                queue.append(v)
    return np.array(poses, dtype=np.float64).reshape(n, 3)


def read_g2o(path: str | os.PathLike[str]) -> PoseGraph:
    """Read a 2D g2o or TORO pose graph.

    Vertices keep their file order; edge endpoints are stored as vertex indices. Vertices named
    in ``FIX`` lines are marked fixed.

    A file without vertex lines takes its vertices from its edges (see the module docstring).
    A UTF-8 byte-order mark at the start is ignored.

    Raises:
        InputFileError: the file is missing or unreadable.
        G2oFormatError: a line is malformed, a tag unknown, a value NaN, a vertex id out of the
            64-bit range, missing or duplicated, an information matrix not positive definite,
            or the file has neither vertices nor edges.

    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFileError(f"{path}: no such file; give the path of a .g2o pose graph") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(
            f"{path}: cannot read the file ({exc}); check it is a text .g2o file"
        ) from None

    ids: list[int] = []
    poses: list[list[float]] = []
    index_of: dict[int, int] = {}
    # (line, id_i, id_j, measurement, information values, format)
    edges: list[tuple[int, int, int, list[float], list[float], str]] = []
    fixed_ids: list[tuple[int, int]] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = line.split()
        tag = tokens[0]
        if tag in _VERTEX_TAGS:
            if len(tokens) < 2:
                raise G2oFormatError(f"{path}:{lineno}: {tag} without a vertex id; fix the line")
            vid = _vertex_id(path, lineno, tag, tokens[1])
            values = _numbers(path, lineno, tag, tokens[2:], 3)
            if vid in index_of:
                raise G2oFormatError(
                    f"{path}:{lineno}: vertex {vid} is defined twice; remove one definition"
                )
            index_of[vid] = len(ids)
            ids.append(vid)
            poses.append(values)
        elif tag in _EDGE_TAGS:
            if len(tokens) < 3:
                raise G2oFormatError(f"{path}:{lineno}: {tag} without two vertex ids; fix the line")
            vi = _vertex_id(path, lineno, tag, tokens[1])
            vj = _vertex_id(path, lineno, tag, tokens[2])
            values = _numbers(path, lineno, tag, tokens[3:], 9)
            if vi == vj:
                raise G2oFormatError(
                    f"{path}:{lineno}: {tag} links vertex {vi} to itself; remove the line"
                )
            edges.append((lineno, vi, vj, values[:3], values[3:], _EDGE_TAGS[tag]))
        elif tag == "FIX":
            for token in tokens[1:]:
                fixed_ids.append((lineno, _vertex_id(path, lineno, tag, token)))
        elif tag in _IGNORED_TAGS:
            continue
        else:
            raise G2oFormatError(
                f"{path}:{lineno}: unknown tag {tag!r}; this reader takes 2D graphs "
                "(VERTEX_SE2/EDGE_SE2, VERTEX2/EDGE2, FIX)"
            )
    from_edges = not ids and bool(edges)
    if from_edges:  # edges only: one vertex per id they name, in id order
        ids = sorted({vid for _, vi, vj, _, _, _ in edges for vid in (vi, vj)})
        index_of = {vid: k for k, vid in enumerate(ids)}
    if not ids:
        raise G2oFormatError(
            f"{path}: no VERTEX_SE2/VERTEX2 or EDGE_SE2/EDGE2 line; is this a 2D g2o pose graph?"
        )

    n_edges = len(edges)
    edge_from = np.empty(n_edges, dtype=np.int64)
    edge_to = np.empty(n_edges, dtype=np.int64)
    measurements = np.empty((n_edges, 3))
    information = np.empty((n_edges, 3, 3))
    for k, (lineno, vi, vj, meas, info, fmt) in enumerate(edges):
        for vid in (vi, vj):
            if vid not in index_of:
                raise G2oFormatError(
                    f"{path}:{lineno}: edge refers to vertex {vid}, which has no VERTEX line; "
                    "add the vertex or remove the edge"
                )
        edge_from[k] = index_of[vi]
        edge_to[k] = index_of[vj]
        measurements[k] = meas
        if fmt == "g2o":
            i11, i12, i13, i22, i23, i33 = info
        else:  # TORO: xx xy yy tt xt yt
            i11, i12, i22, i33, i13, i23 = info
        information[k] = ((i11, i12, i13), (i12, i22, i23), (i13, i23, i33))
    if n_edges:
        eig_min = np.linalg.eigvalsh(information)[:, 0]
        bad = np.flatnonzero(eig_min <= 0.0)
        if bad.size:
            lineno = edges[int(bad[0])][0]
            raise G2oFormatError(
                f"{path}:{lineno}: information matrix is not positive definite; "
                "fix its six values (upper triangle I11 I12 I13 I22 I23 I33)"
            )
    if from_edges:
        poses = chained_poses(edge_from, edge_to, measurements, len(ids)).tolist()
    fixed = np.zeros(len(ids), dtype=bool)
    for lineno, vid in fixed_ids:
        if vid not in index_of:
            raise G2oFormatError(f"{path}:{lineno}: FIX names vertex {vid}, which does not exist")
        fixed[index_of[vid]] = True
    return PoseGraph(
        vertex_ids=np.array(ids, dtype=np.int64),
        poses=np.array(poses, dtype=np.float64),
        edge_from=edge_from,
        edge_to=edge_to,
        measurements=measurements,
        information=information,
        fixed=fixed,
    )


def format_g2o(graph: PoseGraph) -> Iterable[str]:
    """Lines of the g2o text for ``graph`` (``VERTEX_SE2``, ``FIX``, ``EDGE_SE2``)."""
    for vid, (x, y, th) in zip(graph.vertex_ids.tolist(), graph.poses.tolist(), strict=True):
        yield f"VERTEX_SE2 {vid} {x!r} {y!r} {th!r}\n"
    fixed_ids = graph.vertex_ids[graph.fixed].tolist()
    if fixed_ids:
        yield "FIX " + " ".join(str(v) for v in fixed_ids) + "\n"
    ids = graph.vertex_ids
    info = graph.information
    for k in range(graph.num_edges):
        dx, dy, dth = graph.measurements[k].tolist()
        m = info[k]
        upper = (m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
        yield (
            f"EDGE_SE2 {ids[graph.edge_from[k]]} {ids[graph.edge_to[k]]} {dx!r} {dy!r} {dth!r} "
            + " ".join(repr(float(v)) for v in upper)
            + "\n"
        )


def write_g2o(graph: PoseGraph, path: str | os.PathLike[str]) -> None:
    """Write ``graph`` as g2o text, atomically (a reader never sees a half-written file).

    The file gets the user's normal permissions (0666 minus the umask).

    Raises:
        InputFileError: the folder does not exist.
        OSError: the file cannot be written (full disk, read-only folder...); ``path`` is then
            left as it was.

    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise InputFileError(f"{path}: directory {directory} does not exist; create it first")
    with atomic_writer(path) as handle:
        handle.writelines(format_g2o(graph))
