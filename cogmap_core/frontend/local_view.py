"""Local view cells: visual templates and a fast exact template matcher.

As OpenRatSLAM's ``LocalViewMatch``: the camera image is cropped, resampled to a small template
(iRat: 60x20 of rows 0-150), optionally normalised, and compared with every stored template by
the mean absolute difference (MAD) over horizontal shifts.

Resampling (``vt_whole_crop``). OpenRatSLAM's arithmetic (the default): each template pixel is
the mean of a block of whole image pixels, ``floor(crop width / template_x_size)`` wide and
``floor(crop height / template_y_size)`` high, laid from the crop's first column and row; what
the blocks do not reach is dropped (iRat, 416 x 150 crop: 6 x 7 blocks over columns 0-359 and
rows 0-139). Values are kept in steps of 2^-20 (:data:`VALUE_SCALE`), so the integer sums below
are OpenRatSLAM's double-precision errors to within 5e-7. With ``vt_whole_crop = 1`` the whole
crop is area-averaged (any decoded size) and rounded to 8 bits, cogmap's former choice.

Colour (:func:`averages_colour`). OpenRatSLAM is fed a colour camera's images as ``bgr8`` and
averages each pixel's blue, green and red (``convert_view_to_view_template``: a block's sum of
``B + G + R``, divided by ``255 * 3`` and by the block's pixels). In its arithmetic, a colour
image ``(height, width, 3)`` (blue, green, red) is turned into a template the same way, with
the same integer sums and the same two divisions; a grey image as before (the two agree on a
grey image given as three equal channels, to the bit). With ``vt_whole_crop = 1`` a colour image
is converted to its luma first (``cv2.COLOR_BGR2GRAY``), cogmap's former choice.

Matching. The central ``X - 2 s`` columns of the view are compared with columns
``o .. o + X - 2 s`` of the template for the offsets ``o = 0, step, ..., 2 s``. The best
(template, offset) pair is a match when its MAD is at most the threshold; otherwise the view
becomes a new template.

Templates are stored as integers (8-bit intensities, or 2^-20 steps), so the sum of absolute
differences (SAD) is an exact integer: the fast matcher and the exhaustive one compute the very
same numbers, and ties break the same way (lowest template id, then lowest offset, as
OpenRatSLAM's strict ``<`` scan does).

Fast matching. An exhaustive search costs ``T * n_offsets * X' * Y`` absolute differences. The
fast matcher only needs the best pair *if it is a match*, so every pair whose SAD provably exceeds
the bound ``B`` (the threshold, tightened by the SAD of the previous frame's template) is dropped
without computing it. The proof is the triangle inequality: for any partition of the compared
pixels into blocks, ``sum_blocks |sum_block(view) - sum_block(template)| <= SAD``, and so
for any signs ``s_b = +-1``, ``|sum_b s_b (view_b - template_b)| <= SAD``. Two partitions are
precomputed for every (template, offset) pair when the template is stored: 2x4 blocks (level 1)
and 4x4-pixel blocks (level 2). Level 0 is one signed combination of the level-1 block sums,
the *key*: an index sorted by key finds the pairs within ``B`` of the view's key by binary
search; each further level drops pairs whose bound exceeds ``B``, and the survivors get their
exact SAD. A pair with ``SAD <= B`` survives every level, so the result is exactly the
exhaustive search's.

The key's signs are chosen, each time the index is rebuilt, as the combination whose values
spread most over the stored pairs (largest standard deviation): the fewer pairs share the
view's key, the fewer pass level 0. With brightness normalisation every template has about the
same total, so the plain window sum would let most pairs through; the left-right difference
(what the data usually picks) lets through about a third as many. The choice only affects
speed, never the result.

OpenRatSLAM also skips templates whose mean differs from the view's by more than the threshold plus
0.005; that heuristic can reject a true match (the mean covers all columns, the comparison does
not). With ``vt_mean_skip = 1`` (the default, OpenRatSLAM's arithmetic) those templates are
skipped here too, by their exact pixel totals, after the pruned search; with 0 every template is
compared.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError, StateError
from cogmap_core.frontend.compiled import kernels
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.resampling import AreaPlan, BlockPlan

_INITIAL_CAPACITY = 256
#: Template values in OpenRatSLAM's arithmetic are stored as integers in units of 1 / VALUE_SCALE.
VALUE_SCALE = 2**20
_MEAN_EPSILON = 0.005  # OpenRatSLAM's margin of the mean test (local_view_match.cpp)
_LEVEL2_MIN = 24  # pairs left after level 1 below which level 2 is skipped


def averages_colour(config: FrontEndConfig | None) -> bool:
    """Whether colour images keep their colour for ``config`` (None: the defaults).

    True in OpenRatSLAM's arithmetic (``vt_whole_crop = 0``, the default): templates and visual
    odometry average blue, green and red as OpenRatSLAM does; False with ``vt_whole_crop = 1``,
    where readers decode colour images to their luma. Readers decode a colour image in colour
    only when this is True (a grey camera costs nothing more either way).
    """
    return config is None or not config.vt_whole_crop


def grey_image(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """A ``(height, width, 3)`` blue-green-red image as its luma; a grey image as it is."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def check_camera_image(image: object) -> None:
    """Refuse what is neither a grey ``(h, w)`` nor a colour ``(h, w, 3)`` ``uint8`` image."""
    ok = isinstance(image, np.ndarray) and image.dtype == np.uint8
    ok = ok and (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3))  # type: ignore[union-attr]
    if not ok:
        raise InputFileError(
            "camera image must be a 2-D (grey) or 3-channel (blue, green, red) uint8 array, "
            f"got {getattr(image, 'dtype', None)} of shape {getattr(image, 'shape', None)}"
        )


@dataclass(frozen=True, slots=True)
class ViewMatch:
    """Outcome of presenting one view to the local view cells.

    Attributes:
        template_id: the matched template, or the new one when ``is_new``.
        is_new: ``True`` when nothing matched and the view was stored as a new template.
        offset: template column aligned with the view's first compared column (``vt_shift_match``
            means no shift); 0 for a new template.
        relative_rad: heading of the robot now minus its heading when the template was stored,
            from the best shift (positive = turned counter-clockwise); 0 for a new template.
        error: mean absolute difference of the match in [0, 1]; ``None`` for a new template.

    """

    template_id: int
    is_new: bool
    offset: int
    relative_rad: float
    error: float | None


@dataclass(frozen=True, slots=True)
class MatchResult:
    """Best matching (template, offset) pair of a search, or no match.

    Attributes:
        template_id: matched template id, ``-1`` when no pair is within the threshold.
        offset: template offset of the match (``-1`` when none).
        sad: exact sum of absolute differences of the match, in units of the stored values
            (8-bit levels, or 1 / :data:`VALUE_SCALE`; ``-1`` when none).
        candidates: pairs whose exact SAD was computed (for statistics).

    """

    template_id: int
    offset: int
    sad: int
    candidates: int

    @property
    def matched(self) -> bool:
        """Whether a template was within the threshold."""
        return self.template_id >= 0


def _block_edges(n: int, block: int) -> NDArray[np.intp]:
    """Edges of consecutive runs of (about) ``block`` elements covering ``0 .. n``."""
    count = max(1, round(n / block))
    return np.linspace(0, n, count + 1).round().astype(np.intp)


def _block_matrix(n: int, block: int, dtype: type[np.floating[Any]]) -> NDArray[Any]:
    """0/1 matrix ``(n_blocks, n)`` summing consecutive runs of (about) ``block`` elements."""
    edges = _block_edges(n, block)
    count = len(edges) - 1
    m = np.zeros((count, n), dtype=dtype)
    for b in range(count):
        m[b, edges[b] : edges[b + 1]] = 1.0
    return m


class LocalViewCells:
    """The collection of visual templates and the matcher (OpenRatSLAM's ``LocalViewMatch``).

    Index for the pruned search. Level 0 is the key of each (template, offset) pair (a signed
    sum of its level-1 block sums, module doc); the pairs of all templates but the newest few are
    kept sorted by it, so the pairs within ``B`` of the view's key are one contiguous slice found
    by binary search. Their level-1 descriptors (sums
    of 2x4 blocks) are stored in the same order, column-major, so the level-1 bound of the slice
    is a few contiguous passes. The newest templates (fewer than ``max(64, count / 16)``) are
    scanned directly; when there are more, the sorted arrays are rebuilt. Survivors then face the
    level-2 bound (4x4-pixel blocks) and the exact SAD. Block sums are integers, exact in
    ``float32`` (``float64`` for templates so large that a sum could reach 2^24).
    """

    def __init__(self, config: FrontEndConfig) -> None:
        """Create an empty template store for ``config``'s template geometry and threshold."""
        self.config = config
        self._x = config.template_x_size
        self._y = config.template_y_size
        self._shift = config.vt_shift_match
        self._offsets = np.asarray(config.shifts, dtype=np.intp)
        self._n_off = len(self._offsets)
        self._width = self._x - 2 * self._shift  # compared columns
        self._pixels = self._width * self._y
        self._blocks = not config.vt_whole_crop
        #: What an intensity of 1.0 is stored as (255 for 8-bit templates).
        self.value_scale = VALUE_SCALE if self._blocks else 255
        # A pair matches when SAD / (pixels * value_scale) <= threshold; as an integer bound:
        self.max_sad = int(
            math.floor(config.vt_match_threshold * self._pixels * self.value_scale + 1e-6)
        )
        self._mean_skip = bool(config.vt_mean_skip)
        # OpenRatSLAM's mean test |mean(view) - mean(template)| > threshold + 0.005, on totals:
        self._mean_limit = (
            (config.vt_match_threshold + _MEAN_EPSILON) * self._x * self._y * self.value_scale
        )
        crop_fraction = (config.image_crop_x_max - config.image_crop_x_min) / float(
            config.reference_image_width
        )
        self._rad_per_column = math.radians(config.camera_hfov_deg) * crop_fraction / self._x
        # Block partitions of the compared window: (row-sum matrix, column-sum matrix^T).
        dt = np.float32 if self._pixels * self.value_scale < 2**24 else np.float64
        self._dtype = dt
        self._l1 = (_block_matrix(self._y, 10, dt), _block_matrix(self._width, 13, dt).T.copy())
        self._l2 = (_block_matrix(self._y, 4, dt), _block_matrix(self._width, 4, dt).T.copy())
        self._edges1 = (_block_edges(self._y, 10), _block_edges(self._width, 13))
        self._edges2 = (_block_edges(self._y, 4), _block_edges(self._width, 4))
        self._compiled = kernels()
        self._k1 = self._l1[0].shape[0] * self._l1[1].shape[1]
        self._k2 = self._l2[0].shape[0] * self._l2[1].shape[1]
        self._ones1 = np.ones(self._k1, dtype=dt)
        self._ones2 = np.ones(self._k2, dtype=dt)
        self._count = 0
        self._capacity = 0
        store = np.int32 if self._blocks else np.int16
        self._templates = np.zeros((0, self._y, self._x), dtype=store)
        self._sums = np.zeros(0, dtype=np.int64)  # total of each template (the mean test)
        self._keys_all = np.zeros((0, self._n_off), dtype=np.int64)  # level-0 key of each pair
        self._candidates = _key_candidates(self._l1[0].shape[0], self._l1[1].shape[1])
        self._signs = self._candidates[0]
        self._desc1 = np.zeros((0, self._n_off, self._k1), dtype=dt)
        self._desc2 = np.zeros((0, self._n_off, self._k2), dtype=dt)
        self._grow(_INITIAL_CAPACITY)
        # Sorted index over the pairs of templates [0, _indexed).
        self._indexed = 0
        self._keys = np.zeros(0, dtype=np.int64)
        self._ids = np.zeros(0, dtype=np.intp)
        self._sorted1 = np.zeros((self._k1, 0), dtype=dt)
        self._query = np.zeros(2, dtype=np.int64)
        self._plans: dict[tuple[int, ...], AreaPlan | BlockPlan] = {}
        self.last_match: MatchResult | None = None

    # ----------------------------------------------------------------------------- templates
    @property
    def count(self) -> int:
        """Number of stored templates."""
        return self._count

    def template(self, template_id: int) -> NDArray[Any]:
        """Return a stored ``(template_y_size, template_x_size)`` template.

        8-bit (``uint8``) with ``vt_whole_crop``; else ``int32`` in units of 1 / ``value_scale``.
        """
        if not 0 <= template_id < self._count:
            raise IndexError(f"no template {template_id}; there are {self._count}")
        return self._templates[template_id].astype(np.int32 if self._blocks else np.uint8)

    def state_dict(self) -> dict[str, Any]:
        """The stored templates and what the index holds, as plain data; see :meth:`load_state`.

        ``templates`` (``(T, Y, X)`` as :meth:`template` returns them; ``uint8`` when there are
        none), the index's ``indexed`` templates and ``key_signs`` (derived from the templates,
        kept to check them), and the ``last_match`` (a dict, or None).
        """
        templates = (
            np.stack([self.template(k) for k in range(self._count)])
            if self._count
            else np.zeros((0, self._y, self._x), dtype=np.uint8)
        )
        match = self.last_match
        return {
            "templates": templates,
            "key_signs": self._signs.copy(),
            "indexed": self._indexed,
            "last_match": None if match is None else asdict(match),
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Store the templates of :meth:`state_dict` in an empty store, and its last match.

        The same adds rebuild the same index, at the same counts.

        Raises:
            StateError: the store is not empty, or the templates do not rebuild the index
                described.

        """
        if self._count:
            raise StateError("templates can only be loaded into an empty template store")
        for template in state["templates"]:
            self.add(template)
        if self._indexed != state["indexed"] or not np.array_equal(self._signs, state["key_signs"]):
            raise StateError("the view templates do not rebuild the saved index")
        match = state["last_match"]
        self.last_match = None if match is None else MatchResult(**match)

    def make_template(self, image: NDArray[np.uint8]) -> NDArray[Any]:
        """Turn a camera image into a template (as :meth:`template` returns them).

        ``image``: grey ``(height, width)``, or colour ``(height, width, 3)`` (blue, green, red;
        averaged as OpenRatSLAM averages a ``bgr8`` image, module doc).

        The crop is given in pixels of the reference image size and applied at the same
        fractions of the actual image. OpenRatSLAM's arithmetic (``vt_whole_crop = 0``): block
        means of whole pixels (module doc), normalised in double precision as OpenRatSLAM does,
        stored in steps of 1 / ``value_scale``. With ``vt_whole_crop = 1`` the crop (fractional
        edges included, so a frame decoded at a reduced scale gives nearly the same template) is
        resampled by exact area averaging (what ``cv2.resize`` with ``INTER_AREA`` computes;
        here through the integral image, which is several times faster for non-integer scale
        factors), then optionally normalised, in 8 bits.
        """
        check_camera_image(image)
        if not self._blocks:
            image = grey_image(image)  # cogmap's whole crop: the luma of a colour image
        plan = self._plans.get(image.shape)
        if plan is None:
            kind = BlockPlan if self._blocks else AreaPlan
            plan = self._plans[image.shape] = kind(self.config, image.shape, self._x, self._y)
        if isinstance(plan, BlockPlan):
            return self._normalised_blocks(plan.resample(image))
        small = plan.resample(image)
        cfg = self.config
        if cfg.vt_normalisation <= 0 and cfg.vt_patch_normalise <= 0:
            return small
        view = small.astype(np.float64) / 255.0
        if cfg.vt_normalisation > 0:
            mean = float(view.mean())
            if mean > 0:
                view = np.clip(view * (cfg.vt_normalisation / mean), 0.0, 1.0)
        if cfg.vt_patch_normalise > 0:
            view = _patch_normalise(
                view, cfg.vt_patch_normalise, cfg.vt_min_patch_normalisation_std
            )
        return np.rint(view * 255.0).astype(np.uint8)

    def _normalised_blocks(self, view: NDArray[np.float64]) -> NDArray[np.int32]:
        """OpenRatSLAM's normalisations of a block-mean view (in [0, 1]), then fixed point."""
        cfg = self.config
        if cfg.vt_normalisation > 0:
            mean = float(view.sum()) / view.size
            if mean > 0:  # OpenRatSLAM's 0 / 0 of a black view also ends at 0
                view = np.clip(view * cfg.vt_normalisation / mean, 0.0, 1.0)
        if cfg.vt_patch_normalise > 0:
            view = _patch_normalise(
                view, cfg.vt_patch_normalise, cfg.vt_min_patch_normalisation_std
            )
        return np.rint(view * float(VALUE_SCALE)).astype(np.int32)

    def add(self, template: NDArray[Any]) -> int:
        """Store ``template`` and return its id (``0, 1, 2, ...``)."""
        tmpl = self._check(template)
        if self._count == self._capacity:
            self._grow(2 * self._capacity)
        index = self._count
        self._templates[index] = tmpl
        self._sums[index] = int(tmpl.sum(dtype=np.int64))
        windows = np.stack([tmpl[:, o : o + self._width] for o in self._offsets])
        windows = windows.astype(self._dtype)
        self._desc1[index] = (self._l1[0] @ windows @ self._l1[1]).reshape(self._n_off, -1)
        self._desc2[index] = (self._l2[0] @ windows @ self._l2[1]).reshape(self._n_off, -1)
        self._keys_all[index] = self._key_of(self._desc1[index])
        self._count += 1
        if self._count - self._indexed > max(64, self._count // 16):
            self._rebuild_index()
        return index

    def _check(self, template: NDArray[Any]) -> NDArray[Any]:
        want = np.int32 if self._blocks else np.uint8
        if template.shape != (self._y, self._x) or template.dtype != want:
            raise ValueError(
                f"template must be {np.dtype(want)} of shape {(self._y, self._x)}, "
                f"got {template.dtype} {template.shape}"
            )
        if self._blocks and (template.min() < 0 or template.max() > VALUE_SCALE):
            raise ValueError(f"template values must be in [0, {VALUE_SCALE}]")
        return template.astype(self._templates.dtype)

    def _grow(self, capacity: int) -> None:
        n = self._count

        def grown(a: NDArray[Any]) -> NDArray[Any]:
            b = np.zeros((capacity, *a.shape[1:]), dtype=a.dtype)
            b[:n] = a[:n]
            return b

        self._templates = grown(self._templates)
        self._sums = grown(self._sums)
        self._keys_all = grown(self._keys_all)
        self._desc1 = grown(self._desc1)
        self._desc2 = grown(self._desc2)
        # (capacity, Y, n_offsets, width) view of every shifted window, no copy.
        windows = np.lib.stride_tricks.sliding_window_view(self._templates, self._width, axis=2)
        last = int(self._offsets[-1]) + 1
        self._windows = windows[:, :, 0 : last : self.config.vt_step_match, :]  # a view, no copy
        self._capacity = capacity

    def _key_of(self, desc1: NDArray[Any]) -> NDArray[np.int64]:
        """Level-0 keys of level-1 descriptors ``(..., k1)`` (exact integers)."""
        return np.rint(desc1.astype(np.float64) @ self._signs).astype(np.int64)

    def _rebuild_index(self) -> None:
        """Choose the key's signs, then sort the pairs of all templates by key for search."""
        n = self._count
        desc1 = self._desc1[:n].reshape(-1, self._k1).astype(np.float64)
        desc1 -= desc1.mean(axis=0)
        # A key's spread: its variance over the pairs, c^T C c with C the descriptors' covariance
        # (here times the number of pairs): std(desc1 @ c) ranked without the pairs x candidates
        # product.
        scatter = desc1.T @ desc1
        candidates = self._candidates
        spread = np.einsum("ij,jk,ik->i", candidates, scatter, candidates)
        signs = candidates[int(np.argmax(spread))]  # first of the widest: deterministic
        if not np.array_equal(signs, self._signs):
            self._signs = signs
            self._keys_all[:n] = self._key_of(self._desc1[:n])
        keys = self._keys_all[:n].ravel()
        order = np.argsort(keys, kind="stable")
        self._keys = keys[order]
        self._ids = order
        self._sorted1 = np.ascontiguousarray(self._desc1[:n].reshape(-1, self._k1)[order].T)
        self._indexed = n

    # ------------------------------------------------------------------------------ matching
    def match(self, template: NDArray[np.uint8], hint: int | None = None) -> MatchResult:
        """Best (template, offset) pair within the threshold, by the pruned exact search.

        ``hint`` (e.g. the previous frame's template) only speeds the search up: its SAD
        tightens the bound before the cascade. The result is identical to
        :meth:`match_exhaustive`. With ``vt_mean_skip`` templates that fail OpenRatSLAM's mean
        test are left out (of the hint too).
        """
        view = self._check(template)
        count = self._count
        if count == 0:
            return MatchResult(-1, -1, -1, 0)
        if self._compiled is not None:
            return self._match_compiled(view, hint)
        n_off = self._n_off
        centre = view[:, self._shift : self._shift + self._width]
        bound = self.max_sad
        evaluated = 0
        allowed = self._allowed(view) if self._mean_skip else None
        if allowed is not None and hint is not None and 0 <= hint < count and not allowed[hint]:
            hint = None
        if hint is not None and 0 <= hint < count:
            sads = np.abs(self._windows[hint] - centre[:, None, :]).sum(axis=(0, 2))
            evaluated += len(sads)
            bound = min(bound, int(sads.min()))
        fc = centre.astype(self._dtype)
        v1 = (self._l1[0] @ fc @ self._l1[1]).ravel()
        v0 = int(self._key_of(v1))
        found: list[NDArray[np.intp]] = []
        if self._indexed:
            query = self._query
            query[0] = v0 - bound
            query[1] = v0 + bound + 1
            lo, hi = self._keys.searchsorted(query)  # int32 query: no casting of the keys
            if hi > lo:
                d = self._sorted1[:, lo:hi] - v1[:, None]
                np.abs(d, out=d)
                found.append(self._ids[lo:hi][self._ones1 @ d <= bound])
        if count > self._indexed:
            first = self._indexed * n_off
            recent = np.abs(self._keys_all[self._indexed : count].ravel() - v0)
            flat = np.flatnonzero(recent <= bound) + first
            if len(flat):
                d = self._desc1.reshape(-1, self._k1)[flat] - v1
                np.abs(d, out=d)
                found.append(flat[d @ self._ones1 <= bound])
        if not found:
            return MatchResult(-1, -1, -1, evaluated)
        flat = found[0] if len(found) == 1 else np.concatenate(found)
        if allowed is not None:
            flat = flat[allowed[flat // n_off]]
        if len(flat) > _LEVEL2_MIN:  # for a few pairs the exact SAD is as cheap as level 2
            v2 = (self._l2[0] @ fc @ self._l2[1]).ravel()
            d = self._desc2.reshape(-1, self._k2)[flat] - v2
            np.abs(d, out=d)
            flat = flat[d @ self._ones2 <= bound]
        if len(flat) == 0:
            return MatchResult(-1, -1, -1, evaluated)
        t_idx, o_idx = np.divmod(flat, n_off)
        sads = np.abs(self._windows[t_idx, :, o_idx] - centre).sum(axis=(1, 2), dtype=np.int64)
        evaluated += len(sads)
        best_sad = int(sads.min())
        if best_sad > self.max_sad:
            return MatchResult(-1, -1, -1, evaluated)
        # Ties break as the exhaustive scan: lowest template id, then lowest offset.
        best = int(flat[sads == best_sad].min())
        t, o = divmod(best, n_off)
        return MatchResult(t, int(self._offsets[o]), best_sad, evaluated)

    def _match_compiled(self, view: NDArray[Any], hint: int | None) -> MatchResult:
        """:meth:`match` as one compiled loop (:mod:`cogmap_core.frontend.compiled`)."""
        t, o, sad, evaluated = self._compiled.match_pairs(
            view,
            self._templates,
            self._count,
            self._shift,
            self._width,
            self._offsets,
            self._sums,
            self._mean_skip,
            self._mean_limit,
            -1 if hint is None else hint,
            self.max_sad,
            self._edges1,
            self._edges2,
            self._signs,
            self._keys,
            self._ids,
            self._sorted1,
            self._indexed,
            self._keys_all,
            self._desc1.reshape(-1, self._k1),
            self._desc2.reshape(-1, self._k2),
            _LEVEL2_MIN,
        )
        if t < 0:
            return MatchResult(-1, -1, -1, int(evaluated))
        return MatchResult(int(t), int(self._offsets[o]), int(sad), int(evaluated))

    def match_exhaustive(self, template: NDArray[np.uint8]) -> MatchResult:
        """Search exhaustively: exact SAD of all (template, offset) pairs, best within threshold."""
        view = self._check(template)
        count = self._count
        if count == 0:
            return MatchResult(-1, -1, -1, 0)
        centre = view[:, self._shift : self._shift + self._width]
        windows = self._windows[:count]  # (count, Y, n_off, width)
        diff = np.abs(windows - centre[None, :, None, :]).sum(axis=(1, 3), dtype=np.int64)
        if self._mean_skip:
            diff[~self._allowed(view)] = np.iinfo(np.int64).max
        flat = int(np.argmin(diff))  # (template, offset) row-major: first minimum wins
        t, o = divmod(flat, self._n_off)
        sad = int(diff[t, o])
        evaluated = count * self._n_off
        if sad > self.max_sad:
            return MatchResult(-1, -1, -1, evaluated)
        return MatchResult(t, int(self._offsets[o]), sad, evaluated)

    def _allowed(self, view: NDArray[Any]) -> NDArray[np.bool_]:
        """Templates that pass OpenRatSLAM's mean test against ``view`` (one flag each)."""
        total = int(view.sum(dtype=np.int64))
        return np.abs(self._sums[: self._count] - total) <= self._mean_limit

    def observe(self, image: NDArray[np.uint8], hint: int | None = None) -> ViewMatch:
        """Present a camera image: match it or store it as a new template (``on_image``)."""
        template = self.make_template(image)
        result = self.match(template, hint)
        self.last_match = result
        if not result.matched:
            return ViewMatch(self.add(template), True, 0, 0.0, None)
        return ViewMatch(
            result.template_id,
            False,
            result.offset,
            self.relative_rad(result.offset),
            result.sad / (self._pixels * float(self.value_scale)),
        )

    def relative_rad(self, offset: int) -> float:
        """Relative heading implied by a match at template ``offset``.

        The view's column ``shift + i`` matched template column ``offset + i``: the scene moved
        ``shift - offset`` columns to the right in the image, i.e. the robot turned that many
        columns' worth of angle counter-clockwise since the template was stored.
        """
        return (self._shift - offset) * self._rad_per_column


def _key_candidates(row_blocks: int, col_blocks: int) -> NDArray[np.float64]:
    """Sign vectors a level-0 key may use over ``row_blocks x col_blocks`` level-1 blocks.

    The first is all ``+1`` (the window sum). With at most 12 blocks, every sign vector whose
    first sign is ``+1`` (a key and its negative prune alike); with more, the window sum and the
    left-right and top-bottom differences.
    """
    k = row_blocks * col_blocks
    if k <= 12:
        signs = 1 - 2 * ((np.arange(2 ** (k - 1))[:, None] >> np.arange(k - 1)[::-1]) & 1)
        return np.hstack([np.ones((signs.shape[0], 1)), signs]).astype(np.float64)
    cols = np.arange(k) % col_blocks
    rows = np.arange(k) // col_blocks
    left_right = np.where(cols < col_blocks // 2, 1.0, -1.0)
    top_bottom = np.where(rows < row_blocks // 2, 1.0, -1.0)
    return np.stack([np.ones(k), left_right, top_bottom])


def _patch_normalise(view: NDArray[np.float64], radius: int, min_std: float) -> NDArray[np.float64]:
    """Local contrast normalisation over ``(2 radius + 1)^2`` patches (edges replicated)."""
    size = (2 * radius + 1, 2 * radius + 1)
    mean = cv2.blur(view, size, borderType=cv2.BORDER_REPLICATE)
    mean_sq = cv2.blur(view * view, size, borderType=cv2.BORDER_REPLICATE)
    std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    safe = np.where(std > 0, std, 1.0)
    out = np.clip(((view - mean) / safe + 3.0) / 6.0, 0.0, 1.0)
    return np.where(std < min_std, 0.5, out) if min_std > 0 else np.where(std > 0, out, 0.5)
