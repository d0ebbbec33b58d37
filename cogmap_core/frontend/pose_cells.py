"""The pose cell network: a continuous attractor network over (x, y, theta), as in OpenRatSLAM.

Dynamics per odometry update (OpenRatSLAM's ``PosecellNetwork::on_odo``):

1. local excitation: circular convolution with a normalised 3-D Gaussian (7 cells, sigma 1);
2. local inhibition: subtract the circular convolution of the result with a 5-cell, sigma 2
   Gaussian;
3. global inhibition: subtract a constant, clip at 0;
4. normalisation to a total activity of 1;
5. path integration: every theta layer ``k`` (heading ``k * 2 pi / n_th``, which OpenRatSLAM
   lays along ``(sin, cos)`` of ``(x, y)``) is shifted along its heading by the translation in
   cells, with bilinear weights (OpenRatSLAM's four-quadrant
   weights are exactly bilinear interpolation), then the whole network is shifted along theta by
   the rotation in cells with linear weights; everything wraps around;
6. the peak is decoded by population-vector averaging around the most active cell, with
   OpenRatSLAM's arithmetic (cell ``i`` at angle ``(i + 1) 2 pi / n``, then 1 subtracted,
   sums in its order), so a peak that sits on a cell decodes to the same side of it.

Both Gaussian kernels are separable, so the convolutions are three 1-D circulant matrix products
each. Cells are indexed ``[theta, y, x]``.

:class:`PoseCellExperiences` adds the view-cell associations and OpenRatSLAM's experience-map
actions (``on_view_template``, ``get_action``).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import StateError
from cogmap_core.frontend.compiled import kernels
from cogmap_core.frontend.config import FrontEndConfig

FloatArray = NDArray[np.float64]


def _gaussian_1d(dim: int, sigma: float) -> FloatArray:
    """Normalised 1-D factor of OpenRatSLAM's 3-D kernel ``exp(-|d|^2 / (2 sigma^2))``."""
    d = np.arange(dim) - dim // 2
    k = np.exp(-(d * d) / (2.0 * sigma * sigma))
    return k / k.sum()


def _circulant(n: int, kernel: FloatArray) -> FloatArray:
    """Matrix ``M`` with ``(v @ M)[i] = sum_d kernel[d] * v[(i - d + h) % n]``: circular spread."""
    h = len(kernel) // 2
    m = np.zeros((n, n))
    src = np.arange(n)
    for d, w in enumerate(kernel):
        np.add.at(m, (src, (src + d - h) % n), w)
    return m


class PoseCellNetwork:
    """The attractor dynamics of OpenRatSLAM's pose cells (no view or experience bookkeeping)."""

    def __init__(self, config: FrontEndConfig) -> None:
        """Start with all activity in the centre cell, as OpenRatSLAM does."""
        self.config = config
        self.n_xy = config.pc_dim_xy
        self.n_th = config.pc_dim_th
        self.th_size = 2.0 * math.pi / self.n_th
        ex = _gaussian_1d(config.pc_w_e_dim, config.pc_w_e_var)
        ix = _gaussian_1d(config.pc_w_i_dim, config.pc_w_i_var)
        # Right-multiplication spreads along the last axis; the y and theta spreads use the
        # transposes from the left.
        self._e_xy = _circulant(self.n_xy, ex)
        self._e_xy_t = np.ascontiguousarray(self._e_xy.T)
        self._e_th_t = np.ascontiguousarray(_circulant(self.n_th, ex).T)
        self._i_xy = _circulant(self.n_xy, ix)
        self._i_xy_t = np.ascontiguousarray(self._i_xy.T)
        self._i_th_t = np.ascontiguousarray(_circulant(self.n_th, ix).T)
        headings = np.arange(self.n_th) * self.th_size
        self._cos = np.cos(headings)
        self._sin = np.sin(headings)
        # OpenRatSLAM's layout: heading theta moves the activity by (sin, cos) along (x, y), i.e.
        # heading 0 runs along +y and 90 degrees along +x (its layers are rotated by rot90 to
        # move them); the same cells in the same memory order, so ties and sums match too.
        self._cos_sin = np.concatenate([self._sin, self._cos])
        self._edge_loss = [_edge_loss_plan(self.n_xy, self.n_th, back) for back in (False, True)]
        # _perm_xy[m] moves every element m cells forward along an axis: (v @ P[m])[i] = v[i - m].
        self._perm_xy = _permutations(self.n_xy)
        self._perm_th_t = np.ascontiguousarray(_permutations(self.n_th).transpose(0, 2, 1))
        c = config.pc_cells_to_avg
        self._avg_offsets = np.arange(-c, c + 1)
        # OpenRatSLAM's lookups: cell i at angle (i + 1) 2 pi / n (1 is subtracted after atan2).
        angle_xy = (np.arange(self.n_xy) + 1.0) * 2.0 * math.pi / self.n_xy
        angle_th = (np.arange(self.n_th) + 1.0) * 2.0 * math.pi / self.n_th
        self._sincos_xy = np.stack([np.sin(angle_xy), np.cos(angle_xy)], axis=1).tolist()
        self._sincos_th = np.stack([np.sin(angle_th), np.cos(angle_th)], axis=1).tolist()
        self._sincos_xy_array = np.array(self._sincos_xy)
        self._sincos_th_array = np.array(self._sincos_th)
        # compiled decoding while the averaged cells are distinct (ordered as its loops visit them)
        self._compiled = kernels() if 2 * c + 1 <= min(self.n_xy, self.n_th) else None
        self.cells = np.zeros((self.n_th, self.n_xy, self.n_xy))
        bx = by = self.n_xy // 2
        bth = self.n_th // 2
        self.cells[bth, by, bx] = 1.0
        self.best: tuple[float, float, float] = (float(bx), float(by), float(bth))

    def state_dict(self) -> dict[str, Any]:
        """The activity (``cells``, a copy) and its decoded peak (``best``, a list).

        Everything else follows from the settings. :meth:`load_state` restores it.
        """
        return {"cells": self.cells.copy(), "best": list(self.best)}

    def load_state(self, state: dict[str, Any]) -> None:
        """Hold the activity and peak :meth:`state_dict` described.

        Raises:
            StateError: the activity has another shape than this network's settings give.

        """
        cells = np.asarray(state["cells"])
        if cells.shape != self.cells.shape:
            raise StateError("the pose cell network does not match the front-end settings")
        self.cells = cells.astype(np.float64)
        self.best = tuple(float(v) for v in state["best"])  # type: ignore[assignment]

    # ---------------------------------------------------------------------------- dynamics
    def inject(self, x: float, y: float, th: float, energy: float) -> None:
        """Add ``energy`` to the cell of pose-cell coordinates ``(x, y, th)``.

        OpenRatSLAM's arithmetic (``pc_inject_nearest = 0``): the coordinates truncated towards
        zero, nothing when that is outside the network; else the nearest cell, wrapping.
        """
        if not self.config.pc_inject_nearest:
            ix, iy, ith = int(x), int(y), int(th)
            if 0 <= ix < self.n_xy and 0 <= iy < self.n_xy and 0 <= ith < self.n_th:
                self.cells[ith, iy, ix] += energy
            return
        ix = int(math.floor(x + 0.5)) % self.n_xy
        iy = int(math.floor(y + 0.5)) % self.n_xy
        ith = int(math.floor(th + 0.5)) % self.n_th
        self.cells[ith, iy, ix] += energy

    def attractor_step(self) -> None:
        """Local excitation, local inhibition, global inhibition and normalisation."""
        p = self.cells
        n_th, n = self.n_th, self.n_xy
        # Each spread along x or y is one matrix product over all rows of the network: the
        # layers are transposed in between ([th, y, x] -> [th, x, y] -> [th, y, x]).
        a = (p.reshape(-1, n) @ self._e_xy).reshape(n_th, n, n)  # along x
        a = a.transpose(0, 2, 1).reshape(-1, n) @ self._e_xy  # along y: [th, x, y]
        q_xy = self._e_th_t @ a.reshape(n_th, n * n)  # along theta
        r = (q_xy.reshape(-1, n) @ self._i_xy).reshape(n_th, n, n)  # along y
        r = r.transpose(0, 2, 1).reshape(-1, n) @ self._i_xy  # along x: [th, y, x]
        r = self._i_th_t @ r.reshape(n_th, n * n)  # along theta
        q = q_xy.reshape(n_th, n, n).transpose(0, 2, 1) - r.reshape(n_th, n, n)
        q -= self.config.pc_global_inhib
        np.maximum(q, 0.0, out=q)
        total = float(q.sum())
        if total > 0.0:
            q /= total
        else:  # all activity inhibited away (cannot happen with sane parameters): restart
            q[...] = 0.0
            bx, by, bth = self.best
            q[int(bth) % n_th, int(by) % n, int(bx) % n] = 1.0
        self.cells = q

    def path_integrate(self, translation_m: float, rotation_rad: float) -> None:
        """Shift the activity by a forward translation (m) and a rotation (rad), wrapping."""
        v = translation_m / self.config.pc_cell_x_size
        if v != 0.0:
            self.cells = self._translate(self.cells, v)
        if rotation_rad != 0.0:
            # Row k of the result = (1 - f) * row (k - i) + f * row (k - i - 1), rows = theta.
            s = rotation_rad / self.th_size
            i = math.floor(s)
            f = s - i
            perm = self._perm_th_t
            shift = perm[i % self.n_th]
            if f > 0.0:
                shift = (1.0 - f) * shift + f * perm[(i + 1) % self.n_th]
            n = self.n_xy
            self.cells = (shift @ self.cells.reshape(self.n_th, n * n)).reshape(self.n_th, n, n)

    def _translate(self, p: FloatArray, v: float) -> FloatArray:
        """Shift each theta layer by ``v`` cells along its heading (bilinear, wrap-around).

        With ``pc_edge_loss`` (and ``|v| < 1`` cell, all OpenRatSLAM supports) the two shares
        its wrap-around drops are taken off again (:func:`_edge_loss_plan`).
        """
        s = self._shift_matrices(v * self._cos_sin)  # (2 n_th, n, n)
        sx = s[: self.n_th]  # acts on x from the right
        sy_t = s[self.n_th :].transpose(0, 2, 1)  # acts on y from the left
        moved = np.matmul(np.matmul(sy_t, p), sx)
        if self.config.pc_edge_loss and abs(v) < 1.0:
            layers, first, second, dest, cos90, sin90 = self._edge_loss[v < 0]
            a = abs(v) * cos90  # movement along the rotated frame's rows and columns
            b = abs(v) * sin90
            lost = p[layers, first[0], first[1]] * (a * (1.0 - b))
            lost += p[layers, second[0], second[1]] * (b * (1.0 - a))
            moved[layers, dest[0], dest[1]] -= lost
        return moved

    def _shift_matrices(self, d: FloatArray) -> FloatArray:
        """Per-layer ``S`` with ``(row @ S)`` = row shifted by ``d[k]`` cells (linear weights)."""
        whole = np.floor(d)
        frac = (d - whole)[:, None, None]
        first = whole.astype(np.intp) % self.n_xy
        perm = self._perm_xy
        a = perm.take(first, axis=0)
        b = perm.take((first + 1) % self.n_xy, axis=0)
        b -= a
        b *= frac
        a += b
        return a

    def find_best(self) -> tuple[float, float, float]:
        """Decode the activity peak ``(x, y, th)`` in cell units, each in ``[0, dim]``.

        Population-vector (circular mean) decoding over the cells within ``pc_cells_to_avg`` of
        the most active cell (the first maximum in ``[th, y, x]`` order), as OpenRatSLAM's
        ``find_best`` computes it: per-axis sums accumulated in its loop order, then the sine and
        cosine sums over the cells in index order (sequential sums, as its loops).
        """
        p = self.cells
        if self._compiled is not None and p.flags.c_contiguous:
            self.best = self._compiled.decode_peak(
                p, self.config.pc_cells_to_avg, self._sincos_xy_array, self._sincos_th_array
            )
            return self.best
        k, j, i = np.unravel_index(int(np.argmax(p)), p.shape)
        off = self._avg_offsets
        ith = (k + off) % self.n_th
        iy = (j + off) % self.n_xy
        ix = (i + off) % self.n_xy
        sub = p.take(ith, axis=0).take(iy, axis=1).take(ix, axis=2)  # [th, y, x]
        w = len(off)
        # Reductions over a leading axis add row after row: OpenRatSLAM's k-then-j (-then-i) order.
        x_sums = sub.reshape(w * w, w).sum(axis=0)
        y_sums = np.ascontiguousarray(sub.transpose(0, 2, 1)).reshape(w * w, w).sum(axis=0)
        z_sums = np.ascontiguousarray(sub.reshape(w, w * w).T).sum(axis=0)
        x = _ors_decode(x_sums, ix, self._sincos_xy, self.n_xy)
        y = _ors_decode(y_sums, iy, self._sincos_xy, self.n_xy)
        th = _ors_decode(z_sums, ith, self._sincos_th, self.n_th)
        self.best = (x, y, th)
        return self.best

    def update(self, translation_m: float, rotation_rad: float) -> tuple[float, float, float]:
        """One odometry update: attractor step, path integration, peak decoding."""
        self.attractor_step()
        self.path_integrate(translation_m, rotation_rad)
        return self.find_best()

    def distance(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
        """Euclidean distance in cells between two pose-cell coordinates, with wrap-around."""
        return math.sqrt(
            _wrapped(a[0] - b[0], self.n_xy) ** 2
            + _wrapped(a[1] - b[1], self.n_xy) ** 2
            + _wrapped(a[2] - b[2], self.n_th) ** 2
        )


EdgeLossPlan = tuple[
    NDArray[np.intp],
    tuple[NDArray[np.intp], NDArray[np.intp]],
    tuple[NDArray[np.intp], NDArray[np.intp]],
    tuple[NDArray[np.intp], NDArray[np.intp]],
    FloatArray,
    FloatArray,
]


def _edge_loss_plan(n: int, n_th: int, backwards: bool) -> EdgeLossPlan:
    """Where OpenRatSLAM's path integration loses activity, per heading layer.

    OpenRatSLAM rotates each layer by a multiple of 90 degrees (its heading's quadrant; a
    backward move adds 180) so the move points into the first quadrant: ``a = |v| cos(d)``
    cells along the rotated rows and ``b = |v| sin(d)`` along the columns, ``d`` the heading
    within the quadrant. It spreads the layer into a border one cell wider, then folds the far
    row and column back onto the first ones, but both loops start at index 1: the share
    ``a (1 - b)`` of the cell in the last row and first column, and ``b (1 - a)`` of the cell in
    the first row and last column, which would wrap into the first cell, are dropped. Returns
    the layers, those two cells and the first cell in unrotated ``(y, x)`` indices, and each
    layer's ``cos(d)`` and ``sin(d)``, computed as OpenRatSLAM does.
    """
    size = (2.0 * math.pi) / n_th
    last = n - 1
    # the rotated frame's rows and columns as (axis, forward?) of the layer, per quadrant
    frames = {
        0: (("y", True), ("x", True)),
        1: (("x", True), ("y", False)),
        2: (("y", False), ("x", False)),
        3: (("x", False), ("y", True)),
    }
    first_y, first_x, second_y, second_x, dest_y, dest_x, cos90, sin90 = ([] for _ in range(8))
    for k in range(n_th):
        direction = k * size + (math.pi if backwards else 0.0)
        turns = math.floor(direction * 2.0 / math.pi)
        d90 = direction - turns * math.pi / 2
        (row_axis, row_fwd), (col_axis, col_fwd) = frames[turns % 4]
        far_row, up_row = (last, 0) if row_fwd else (0, last)
        far_col, up_col = (last, 0) if col_fwd else (0, last)

        def cell(row: int, col: int, row_axis: str = row_axis) -> tuple[int, int]:
            return (row, col) if row_axis == "y" else (col, row)  # -> (y, x)

        for (ys, xs), (y, x) in (
            ((first_y, first_x), cell(far_row, up_col)),
            ((second_y, second_x), cell(up_row, far_col)),
            ((dest_y, dest_x), cell(up_row, up_col)),
        ):
            ys.append(y)
            xs.append(x)
        cos90.append(math.cos(d90))
        sin90.append(math.sin(d90))

    def pair(ys: list[int], xs: list[int]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        return np.array(ys, dtype=np.intp), np.array(xs, dtype=np.intp)

    return (
        np.arange(n_th),
        pair(first_y, first_x),
        pair(second_y, second_x),
        pair(dest_y, dest_x),
        np.array(cos90),
        np.array(sin90),
    )


def _permutations(n: int) -> FloatArray:
    """``P[m]`` (n x n) with ``(v @ P[m])[i] = v[(i - m) % n]``: a circular shift by ``m``."""
    src = np.arange(n)[None, :, None]
    dst = np.arange(n)[None, None, :]
    m = np.arange(n)[:, None, None]
    return ((dst - src) % n == m).astype(np.float64)


def _ors_decode(
    sums: FloatArray, cells: NDArray[np.intp], sincos: list[list[float]], dim: int
) -> float:
    """OpenRatSLAM's circular mean of per-cell ``sums`` (at ``cells``): cells in index order."""
    s = c = 0.0
    # sequential double sums, as its loop over the cells (few: plain floats are fastest)
    for cell, total in sorted(zip(cells.tolist(), sums.tolist(), strict=True)):
        sin_cell, cos_cell = sincos[cell]
        s += sin_cell * total
        c += cos_cell * total
    value = math.atan2(s, c) * dim / (2.0 * math.pi) - 1.0
    while value < 0:
        value += dim
    while value > dim:
        value -= dim
    return value


def _wrapped(delta: float, dim: int) -> float:
    d = abs(delta) % dim
    return min(d, dim - d)


class ActionKind(enum.Enum):
    """Experience-map actions of OpenRatSLAM's ``PosecellNetwork::get_action``."""

    NO_ACTION = 0
    CREATE_NODE = 1
    CREATE_EDGE = 2
    SET_NODE = 3


@dataclass(frozen=True, slots=True)
class Action:
    """One experience-map action: ``src`` is the current experience before it, ``dest`` after."""

    kind: ActionKind
    src: int
    dest: int
    relative_rad: float


@dataclass(slots=True)
class _ViewCell:
    """Pose-cell association of one view template."""

    x: float
    y: float
    th: float
    decay: float
    decay_frame: int  # frame at which ``decay`` was last written
    experiences: list[int]


class PoseCellExperiences:
    """Pose cells with view-cell energy injection and experience-map actions (OpenRatSLAM).

    Call :meth:`on_view_template` and :meth:`on_odo` once per frame, then :meth:`get_action`.
    """

    def __init__(self, config: FrontEndConfig) -> None:
        """Create the network; no templates or experiences yet."""
        self.config = config
        self.network = PoseCellNetwork(config)
        self._views: list[_ViewCell] = []
        self._experiences: list[tuple[float, float, float]] = []
        self._experience_vt: list[int] = []
        self.current_vt = 0
        self.prev_vt = 0
        self.current_exp = 0
        self._vt_delta_th = 0.0  # relative angle of the last view, in theta cells
        self._frame = 0
        self._odo_update = False
        self._vt_update = False

    def state_dict(self) -> dict[str, Any]:
        """Everything but the settings, as plain data (copies); :meth:`load_state` restores it.

        ``network`` (:meth:`PoseCellNetwork.state_dict`); per view template, its view cell's
        pose-cell coordinates (``view_cell_pose``, ``(V, 3)``), decay and the frame it was
        written at, and its experiences (``view_cell_experiences``, lists of ids); per
        experience, its pose-cell coordinates (``experiences``, ``(E, 3)``) and view template
        (``experience_view``); and the scalars ``current_vt``, ``prev_vt``, ``current_exp``,
        ``vt_delta_th`` (the last view's relative angle in theta cells), ``frame``,
        ``odo_update`` and ``vt_update``.
        """
        views = self._views
        return {
            "network": self.network.state_dict(),
            "view_cell_pose": np.array([(v.x, v.y, v.th) for v in views]).reshape(-1, 3),
            "view_cell_decay": np.array([v.decay for v in views], dtype=np.float64),
            "view_cell_decay_frame": np.array([v.decay_frame for v in views], dtype=np.int64),
            "view_cell_experiences": [list(v.experiences) for v in views],
            "experiences": np.array(self._experiences, dtype=np.float64).reshape(-1, 3),
            "experience_view": np.array(self._experience_vt, dtype=np.int64),
            "current_vt": self.current_vt,
            "prev_vt": self.prev_vt,
            "current_exp": self.current_exp,
            "vt_delta_th": self._vt_delta_th,
            "frame": self._frame,
            "odo_update": self._odo_update,
            "vt_update": self._vt_update,
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Hold the state :meth:`state_dict` described.

        Raises:
            StateError: a pose cell network of another shape (:meth:`PoseCellNetwork.load_state`).

        """
        self.network.load_state(state["network"])
        pose = np.asarray(state["view_cell_pose"]).tolist()
        decay = np.asarray(state["view_cell_decay"]).tolist()
        decay_frame = np.asarray(state["view_cell_decay_frame"]).tolist()
        self._views = [
            _ViewCell(p[0], p[1], p[2], d, f, list(e))
            for p, d, f, e in zip(
                pose, decay, decay_frame, state["view_cell_experiences"], strict=True
            )
        ]
        self._experiences = [tuple(e) for e in np.asarray(state["experiences"]).tolist()]
        self._experience_vt = np.asarray(state["experience_view"]).tolist()
        self.current_vt = int(state["current_vt"])
        self.prev_vt = int(state["prev_vt"])
        self.current_exp = int(state["current_exp"])
        self._vt_delta_th = float(state["vt_delta_th"])
        self._frame = int(state["frame"])
        self._odo_update = bool(state["odo_update"])
        self._vt_update = bool(state["vt_update"])

    @property
    def experience_count(self) -> int:
        """Number of experiences created so far."""
        return len(self._experiences)

    def experience_pose_cells(self, exp_id: int) -> tuple[float, float, float]:
        """Pose-cell coordinates ``(x, y, th)`` recorded for experience ``exp_id``."""
        return self._experiences[exp_id]

    def experience_view(self, exp_id: int) -> int:
        """The view template experience ``exp_id`` was created with."""
        return self._experience_vt[exp_id]

    def view_decay(self, vt: int) -> float:
        """Return the current decay of view cell ``vt`` (grows while the view persists)."""
        return self._decay_now(self._views[vt])

    def _decay_now(self, cell: _ViewCell) -> float:
        """Decay after this frame's restore; every cell recovers by ``pc_vt_restore`` a frame."""
        restored = cell.decay - self.config.pc_vt_restore * (self._frame - cell.decay_frame)
        return max(self.config.vt_active_decay, restored)

    def on_view_template(self, vt: int, relative_rad: float) -> None:
        """Take the frame's view template (``vt`` is new iff it equals the number of templates).

        A familiar view that is not among the ``vt_recent_no_inject`` newest injects energy at the
        pose cells it was first seen at, shifted in theta by the relative angle. The energy falls
        with the view cell's decay, which grows while the same view persists (OpenRatSLAM's
        ``PC_VT_INJECT_ENERGY / 30 * (30 - exp(1.2 * decay))``) and recovers when it does not.
        """
        cfg = self.config
        self._frame += 1
        n_th = self.network.n_th
        # The relative angle of the current view, in theta cells (0 for a new template).
        self._vt_delta_th = relative_rad / (2.0 * math.pi) * n_th
        if vt > len(self._views):
            raise ValueError(f"view template {vt} skips ids; {len(self._views)} known")
        if vt == len(self._views):
            x, y, th = self.network.best
            self._views.append(_ViewCell(x, y, th, cfg.vt_active_decay, self._frame, []))
        else:
            cell = self._views[vt]
            decay = max(
                cfg.vt_active_decay,
                cell.decay - cfg.pc_vt_restore * (self._frame - 1 - cell.decay_frame),
            )
            if self._may_inject(vt):
                if vt == self.current_vt:
                    decay += cfg.vt_active_decay
                energy = cfg.pc_vt_inject_energy / 30.0 * (30.0 - math.exp(1.2 * decay))
                if energy > 0.0:
                    th = (cell.th + self._vt_delta_th) % n_th
                    self.network.inject(cell.x, cell.y, th, energy)
            # This frame's restore for this cell, then remember when it was written.
            cell.decay = max(cfg.vt_active_decay, decay - cfg.pc_vt_restore)
            cell.decay_frame = self._frame
        self.prev_vt = self.current_vt
        self.current_vt = vt
        self._vt_update = True

    def _may_inject(self, vt: int) -> bool:
        """Whether familiar view ``vt`` injects energy (not among the newest templates).

        OpenRatSLAM tests ``vt < visual_templates.size() - 10`` in unsigned arithmetic: while
        there are fewer than 10 (``vt_recent_no_inject``) templates the difference wraps around
        and every familiar view injects (``pc_inject_nearest = 0``); otherwise none of the
        newest do.
        """
        known, recent = len(self._views), self.config.vt_recent_no_inject
        if not self.config.pc_inject_nearest and known < recent:
            return True
        return vt + recent < known

    def on_odo(self, translation_m: float, rotation_rad: float) -> None:
        """Odometry since the previous frame: one network update."""
        self.network.update(translation_m, rotation_rad)
        self._odo_update = True

    def _delta_pc(self, exp: tuple[float, float, float]) -> float:
        """Pose-cell distance from the peak (theta corrected by the view's angle) to ``exp``."""
        x, y, th = self.network.best
        corrected = (th - self._vt_delta_th) % self.network.n_th
        return self.network.distance((x, y, corrected), exp)

    def _create_experience(self) -> int:
        self._experiences.append(self.network.best)
        self._experience_vt.append(self.current_vt)
        self.current_exp = len(self._experiences) - 1
        self._views[self.current_vt].experiences.append(self.current_exp)
        return self.current_exp

    def get_action(self) -> Action:
        """Decide the experience-map action once a view and odometry arrived (``get_action``).

        - no experience yet, or the current view has none: create one;
        - else, when the peak moved more than ``exp_delta_pc_threshold`` cells from the current
          experience or the view changed: the closest other experience of the current view within
          the threshold becomes current through a new link (loop closure), or, if none is close
          enough, a new experience is created;
        - otherwise nothing.

        (OpenRatSLAM's code also names a ``SET_NODE`` outcome, but its conditions never produce
        it; a link is always followed by setting the current experience.)
        """
        if not (self._odo_update and self._vt_update):
            return Action(ActionKind.NO_ACTION, self.current_exp, self.current_exp, 0.0)
        self._odo_update = self._vt_update = False
        src = self.current_exp
        rel = self.relative_rad
        if not self._views:
            return Action(ActionKind.NO_ACTION, src, src, 0.0)
        exps = self._views[self.current_vt].experiences
        if not self._experiences or not exps:
            return Action(ActionKind.CREATE_NODE, src, self._create_experience(), 0.0)
        threshold = self.config.exp_delta_pc_threshold
        moved = self._delta_pc(self._experiences[self.current_exp]) > threshold
        if not (moved or self.current_vt != self.prev_vt):
            return Action(ActionKind.NO_ACTION, src, src, 0.0)
        best_id, best_delta = -1, math.inf
        for exp_id in exps:
            if exp_id == self.current_exp:
                continue
            delta = self._delta_pc(self._experiences[exp_id])
            if delta < best_delta:
                best_id, best_delta = exp_id, delta
        if best_delta < threshold:
            self.current_exp = best_id
            return Action(ActionKind.CREATE_EDGE, src, best_id, rel)
        return Action(ActionKind.CREATE_NODE, src, self._create_experience(), 0.0)

    @property
    def relative_rad(self) -> float:
        """Relative angle of the current view match (``get_relative_rad``), radians."""
        return self._vt_delta_th * 2.0 * math.pi / self.network.n_th
