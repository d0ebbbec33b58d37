"""The view template's resampling of a camera image, one plan per decoded image size.

:class:`BlockPlan` is OpenRatSLAM's arithmetic (means of whole-pixel blocks, ``vt_whole_crop =
0``), :class:`AreaPlan` cogmap's former whole-crop area averaging (``vt_whole_crop = 1``); the
local view cells (:mod:`cogmap_core.frontend.local_view`) keep one plan per image shape.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError
from cogmap_core.frontend.compiled import kernels
from cogmap_core.frontend.config import FrontEndConfig


class BlockPlan:
    """OpenRatSLAM's template geometry for one image size: means of whole-pixel blocks.

    The crop (reference pixels, scaled to the decoded size and rounded) is cut into blocks of
    ``floor(crop width / out_x)`` by ``floor(crop height / out_y)`` pixels from its first column
    and row; pixels past the last whole block are not used (``convert_view_to_view_template``).
    """

    def __init__(
        self, config: FrontEndConfig, shape: tuple[int, ...], out_x: int, out_y: int
    ) -> None:
        height, width = shape[0], shape[1]
        sx = width / config.reference_image_width
        sy = height / config.reference_image_height
        x0 = round(config.image_crop_x_min * sx)
        x1 = min(width, round(config.image_crop_x_max * sx))
        y0 = round(config.image_crop_y_min * sy)
        y1 = min(height, round(config.image_crop_y_max * sy))
        self.bx = (x1 - x0) // out_x
        self.by = (y1 - y0) // out_y
        if self.bx < 1 or self.by < 1:
            min_w, min_h = config.minimum_image_size()
            raise InputFileError(
                f"camera images of {width}x{height} px (as decoded) are too small for the "
                f"{out_x}x{out_y} view template: their crop is {x1 - x0}x{y1 - y0} px; "
                f"images must be at least {min_w}x{min_h} px as decoded"
            )
        self.rows = slice(y0, y0 + self.by * out_y)
        self.cols = slice(x0, x0 + self.bx * out_x)
        self.out_x, self.out_y = out_x, out_y
        self.divisor = float(self.bx * self.by)
        # block corners in the integral image of the used part
        self.ys = np.arange(out_y + 1) * self.by
        self.xs = np.arange(out_x + 1) * self.bx
        self.compiled = kernels()
        self.abs_ys = self.ys + y0
        self.abs_xs = self.xs + x0

    def resample(self, image: NDArray[np.uint8]) -> NDArray[np.float64]:
        """Block means in [0, 1]: ``sum / 255 / pixels`` as OpenRatSLAM divides.

        The block sums are exact integers, from the integral image (OpenCV's, in float64: exact
        up to 2^53). A colour image's blocks sum blue, green and red, divided by ``255 * 3``
        then by the pixels (OpenRatSLAM's ``bgr8`` branch): each block's ``bx * 3`` bytes of a
        row summed at once (``cv2.reduce``, in 32-bit integers), then its ``by`` rows. With
        numba, one compiled loop adds the same integers (:mod:`cogmap_core.frontend.compiled`).
        """
        crop = image[self.rows, self.cols]
        if self.compiled is not None:
            sums = np.empty((self.out_y, self.out_x), dtype=np.int64)
            depth = 3 if image.ndim == 3 else 1
            flat = np.ascontiguousarray(image).reshape(image.shape[0], -1)
            self.compiled.block_sums(flat, depth, self.abs_ys, self.abs_xs, sums)
            return sums.astype(np.float64) / (765.0 if crop.ndim == 3 else 255.0) / self.divisor
        if crop.ndim == 3:
            rows = crop.reshape(self.by * self.out_y * self.out_x, self.bx * 3)
            per_row = cv2.reduce(rows, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S)
            sums = per_row.reshape(self.out_y, self.by, self.out_x).sum(axis=1, dtype=np.int64)
            return sums.astype(np.float64) / 765.0 / self.divisor
        corners = cv2.integral(crop, sdepth=cv2.CV_64F).take(self.ys, axis=0).take(self.xs, axis=1)
        sums = corners[1:, 1:] - corners[:-1, 1:] - corners[1:, :-1] + corners[:-1, :-1]
        return sums / 255.0 / self.divisor


class AreaPlan:
    """Area resampling of the crop of one image size, precomputed (fractional crop edges).

    Small crops (e.g. frames decoded at 1/2 or 1/4 scale) use two products with the area-weight
    matrices; large ones interpolate the integral image at the cell corners, which does less
    work. Both give the exact area means up to floating-point rounding.
    """

    _MATRIX_LIMIT = 40_000  # crop pixels up to which the matrix products are cheaper

    def __init__(
        self, config: FrontEndConfig, shape: tuple[int, ...], out_x: int, out_y: int
    ) -> None:
        height, width = shape[0], shape[1]
        sy = height / config.reference_image_height
        sx = width / config.reference_image_width
        y0, y1 = config.image_crop_y_min * sy, config.image_crop_y_max * sy
        x0, x1 = config.image_crop_x_min * sx, config.image_crop_x_max * sx
        if y1 - y0 < out_y - 1e-9 or x1 - x0 < out_x - 1e-9:
            min_w, min_h = config.minimum_image_size()
            raise InputFileError(
                f"camera images of {width}x{height} px (as decoded) are too small for the "
                f"{out_x}x{out_y} view template: their crop is {x1 - x0:.4g}x{y1 - y0:.4g} px; "
                f"images must be at least {min_w}x{min_h} px as decoded"
            )
        self.rows = min(height, math.ceil(y1 - 1e-9))
        self.cols = min(width, math.ceil(x1 - 1e-9))
        ys = np.linspace(y0, y1, out_y + 1)
        xs = np.linspace(x0, x1, out_x + 1)
        self.use_matrices = self.rows * self.cols <= self._MATRIX_LIMIT
        if self.use_matrices:
            self.wy = _area_weights(ys, self.rows).astype(np.float32)
            self.wx = np.ascontiguousarray(_area_weights(xs, self.cols).T).astype(np.float32)
        self.iy = np.minimum(np.floor(ys).astype(np.intp), self.rows - 1)
        self.iy1 = self.iy + 1
        self.fy = (ys - self.iy)[:, None]
        self.ix = np.minimum(np.floor(xs).astype(np.intp), self.cols - 1)
        self.ix1 = self.ix + 1
        self.fx = xs - self.ix
        self.inv_area = 1.0 / ((y1 - y0) / out_y * (x1 - x0) / out_x)

    def resample(self, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Mean of the image over each output cell, rounded to 8 bits.

        The integral of a piecewise-constant image is exactly bilinear inside each pixel, so
        interpolating the integral image at the cell corners gives exact area sums.
        """
        crop = image[: self.rows, : self.cols]
        if self.use_matrices:
            cells = (self.wy @ crop) @ self.wx
        else:
            integral = cv2.integral(crop, sdepth=cv2.CV_64F)  # (rows + 1, cols + 1)
            a = integral.take(self.iy, axis=0)
            b = integral.take(self.iy1, axis=0)
            b -= a
            b *= self.fy
            a += b
            g = a.take(self.ix, axis=1)
            h = a.take(self.ix1, axis=1)
            h -= g
            h *= self.fx
            g += h
            cells = g[1:, 1:] - g[:-1, 1:] - g[1:, :-1] + g[:-1, :-1]
            cells *= self.inv_area
        # Means of 8-bit values lie in [0, 255] up to rounding error far below 0.5: no clipping.
        return np.rint(cells, out=cells).astype(np.uint8)


def _area_weights(edges: NDArray[np.float64], n_in: int) -> NDArray[np.float64]:
    """Row ``i``: the fraction of output cell ``[edges[i], edges[i+1])`` in each input pixel."""
    lo = np.arange(n_in)[None, :]
    overlap = np.minimum(edges[1:, None], lo + 1) - np.maximum(edges[:-1, None], lo)
    w = np.clip(overlap, 0.0, None)
    return w / w.sum(axis=1, keepdims=True)


__all__ = ["AreaPlan", "BlockPlan"]
