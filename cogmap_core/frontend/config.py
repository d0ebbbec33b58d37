"""Typed, validated parameters of the SLAM front end (OpenRatSLAM ``config_irataus`` defaults).

Names follow OpenRatSLAM's settings (``local_view_match.cpp``, ``posecell_network.cpp``) so a
value can be looked up in its config files. Defaults are the iRat Australia values of
``config/config_irataus.txt``; settings that file leaves out take OpenRatSLAM's built-in default.
A few constants that OpenRatSLAM hard-codes are exposed too (``pc_cells_to_avg``,
``vt_recent_no_inject``), and ``camera_hfov_deg`` is new (see :class:`FrontEndConfig`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from cogmap_core.config import is_finite_number, short_repr
from cogmap_core.errors import ParameterError

# name -> (lower, lower inclusive?, upper, upper inclusive?, integer?, meaning)
_RANGES: dict[str, tuple[float, bool, float, bool, bool, str]] = {
    "reference_image_width": (1, True, 100_000, True, True, "width the crop is given in (px)"),
    "reference_image_height": (1, True, 100_000, True, True, "height the crop is given in (px)"),
    "image_crop_x_min": (0, True, 100_000, True, True, "first cropped column (px)"),
    "image_crop_x_max": (1, True, 100_000, True, True, "end of the cropped columns (px)"),
    "image_crop_y_min": (0, True, 100_000, True, True, "first cropped row (px)"),
    "image_crop_y_max": (1, True, 100_000, True, True, "end of the cropped rows (px)"),
    "template_x_size": (3, True, 1000, True, True, "template width (px)"),
    "template_y_size": (1, True, 1000, True, True, "template height (px)"),
    "vt_shift_match": (0, True, 499, True, True, "largest horizontal shift tried (template px)"),
    "vt_step_match": (1, True, 999, True, True, "step between tried shifts (template px)"),
    "vt_match_threshold": (0.0, True, 1.0, True, False, "largest mean abs difference of a match"),
    "vt_normalisation": (0.0, True, 1e3, True, False, "global brightness normalisation (0 = off)"),
    "vt_patch_normalise": (0, True, 100, True, True, "patch normalisation radius (0 = off)"),
    "vt_min_patch_normalisation_std": (0.0, True, 1.0, True, False, "min std of a patch"),
    "camera_hfov_deg": (0.0, True, 360.0, True, False, "horizontal field of view (deg)"),
    "pc_dim_xy": (3, True, 1000, True, True, "pose cells along x and y"),
    "pc_dim_th": (3, True, 3600, True, True, "pose cells along theta"),
    "pc_w_e_dim": (1, True, 1000, True, True, "excitation kernel size (odd, cells)"),
    "pc_w_i_dim": (1, True, 1000, True, True, "inhibition kernel size (odd, cells)"),
    "pc_w_e_var": (0.0, False, 1e3, True, False, "excitation kernel spread (cells)"),
    "pc_w_i_var": (0.0, False, 1e3, True, False, "inhibition kernel spread (cells)"),
    "pc_global_inhib": (0.0, True, 1.0, False, False, "global inhibition per update"),
    "pc_vt_inject_energy": (0.0, True, 1e3, True, False, "view-cell energy injection"),
    "pc_cell_x_size": (0.0, False, 1e3, True, False, "pose cell size (m)"),
    "pc_vt_restore": (0.0, True, 1e3, True, False, "view-cell decay restored per frame"),
    "vt_active_decay": (0.0, False, 1e3, True, False, "view-cell decay added per repeat"),
    "vt_recent_no_inject": (0, True, 1_000_000, True, True, "newest templates that inject nothing"),
    "pc_cells_to_avg": (0, True, 1000, True, True, "cells each side used to find the peak"),
    "exp_delta_pc_threshold": (0.0, False, 1e6, True, False, "pose-cell distance of a new place"),
    "vt_whole_crop": (0, True, 1, True, True, "1 = area mean of the whole crop, 0 = OpenRatSLAM"),
    "vt_mean_skip": (0, True, 1, True, True, "1 = skip templates of another mean (OpenRatSLAM)"),
    "pc_update_per_odometry": (0, True, 1, True, True, "1 = a pose-cell update per odometry"),
    "pc_inject_nearest": (0, True, 1, True, True, "1 = inject at the nearest cell, 0 = truncate"),
    "pc_edge_loss": (0, True, 1, True, True, "1 = OpenRatSLAM's wrap that loses two edge cells"),
    "vtrans_image_x_min": (0, True, 100_000, True, True, "first column of the speed strip (px)"),
    "vtrans_image_x_max": (1, True, 100_000, True, True, "end of the speed strip's columns (px)"),
    "vtrans_image_y_min": (0, True, 100_000, True, True, "first row of the speed strip (px)"),
    "vtrans_image_y_max": (1, True, 100_000, True, True, "end of the speed strip's rows (px)"),
    "vrot_image_x_min": (0, True, 100_000, True, True, "first column of the rotation strip (px)"),
    "vrot_image_x_max": (1, True, 100_000, True, True, "end of the rotation strip's columns (px)"),
    "vrot_image_y_min": (0, True, 100_000, True, True, "first row of the rotation strip (px)"),
    "vrot_image_y_max": (1, True, 100_000, True, True, "end of the rotation strip's rows (px)"),
    "camera_fov_deg": (0.0, False, 360.0, True, False, "camera field of view (deg)"),
    "camera_hz": (0.0, True, 1000.0, True, False, "camera rate (Hz; 0 = the frame times')"),
    "vtrans_scaling": (0.0, False, 1e9, True, False, "speed per unit of profile difference"),
    "vtrans_max": (0.0, False, 1e6, True, False, "largest visual speed (m/s)"),
}

#: cogmap's own front-end arithmetic before it followed OpenRatSLAM's (issue 26): the area mean
#: of the whole crop as 8-bit templates, an exact search over every template, one pose-cell
#: update per camera frame, injection at the nearest cell and none by the 10 newest templates.
COGMAP_ARITHMETIC: dict[str, int] = {
    "vt_whole_crop": 1,
    "vt_mean_skip": 0,
    "pc_update_per_odometry": 0,
    "pc_inject_nearest": 1,
    "pc_edge_loss": 0,
}


@dataclass(frozen=True, slots=True)
class FrontEndConfig:
    """Parameters of the local view cells and the pose cell network.

    Local view (visual templates):

    Attributes:
        reference_image_width: image width the crop columns are given in (iRat: 416 px).
        reference_image_height: image height the crop rows are given in (iRat: 240 px). An image
            of another size (e.g. decoded at 1/2 or 1/4 scale) is cropped at the same fractions.
        image_crop_x_min: first column of the crop, in reference pixels.
        image_crop_x_max: end (exclusive) of the crop columns, in reference pixels.
        image_crop_y_min: first row of the crop, in reference pixels.
        image_crop_y_max: end (exclusive) of the crop rows (iRat: 150 of 240).
        template_x_size: template width after area resampling (iRat: 60).
        template_y_size: template height (iRat: 20).
        vt_shift_match: largest horizontal shift in template pixels tried each way (iRat: 4).
        vt_step_match: step between tried shifts (iRat: 1).
        vt_match_threshold: a view matches a template when the mean absolute difference (intensity
            in [0, 1]) over the overlapping columns at the best shift is at most this (iRat: 0.03).
        vt_normalisation: if > 0, scale the template so its mean is this value (clipped to
            [0, 1]); 0 disables (iRat).
        vt_patch_normalise: if > 0, local contrast normalisation over a (2r+1)^2 patch; 0
            disables (iRat).
        vt_min_patch_normalisation_std: patches flatter than this become 0.5.
        camera_hfov_deg: horizontal field of view of the reference crop, used to turn the best
            shift into the relative angle passed on with a match. OpenRatSLAM passes 0 for a
            non-panoramic camera; 0 here does the same.

    Pose cells:

    Attributes:
        pc_dim_xy: cells along x and along y (iRat: 11).
        pc_dim_th: cells along theta (default 36, i.e. 10 degrees each).
        pc_w_e_dim: size of the 3-D Gaussian excitation kernel (7).
        pc_w_i_dim: size of the inhibition kernel (5).
        pc_w_e_var: standard deviation of the excitation kernel in cells (1).
        pc_w_i_var: standard deviation of the inhibition kernel in cells (2).
        pc_global_inhib: subtracted from every cell after local inhibition (0.00002).
        pc_vt_inject_energy: energy a familiar view injects (iRat: 0.1).
        pc_cell_x_size: metres per pose cell (iRat: 0.015).
        pc_vt_restore: each view cell's decay recovers by this each frame (0.05).
        vt_active_decay: decay added each frame a view cell stays active (iRat: 1.0).
        vt_recent_no_inject: the newest templates inject nothing (OpenRatSLAM: 10).
        pc_cells_to_avg: cells each side of the maximum used to decode the peak (3).
        exp_delta_pc_threshold: pose-cell distance beyond which the place is new (iRat: 2).

    Arithmetic (defaults: OpenRatSLAM's; :data:`COGMAP_ARITHMETIC` gives cogmap's former own):

    Attributes:
        vt_whole_crop: 0 = OpenRatSLAM's template: the mean of whole-pixel blocks of
            ``floor(crop width / template_x_size)`` by ``floor(crop height / template_y_size)``
            pixels of the image as decoded, from the crop's first column and row (iRat's
            416 x 150 crop: 6 x 7 pixel blocks covering columns 0-359 and rows 0-139), kept at
            full precision (values in steps of 2^-20). 1 = the exact area mean of the whole crop
            (any decoded size, e.g. a JPEG decoded at 1/4 scale), rounded to 8 bits.
        vt_mean_skip: 1 = a template whose mean differs from the view's by more than
            ``vt_match_threshold + 0.005`` is not compared (OpenRatSLAM's shortcut; it can
            reject the best match); 0 = every template is compared.
        pc_update_per_odometry: 1 = the pose cells are updated once per odometry message and
            the experience-map action is decided at the first odometry message after a camera
            frame (OpenRatSLAM's nodes); 0 = one update per camera frame with the odometry since
            the previous frame, and the action decided right away.
        pc_inject_nearest: 0 = a familiar view injects at its cell coordinates truncated
            towards zero, and while fewer than 10 templates exist every familiar view injects
            (OpenRatSLAM's ``vt < size() - 10`` in unsigned arithmetic); 1 = at the nearest
            cell, never by the ``vt_recent_no_inject`` newest templates.
        pc_edge_loss: 1 = path integration wraps around as OpenRatSLAM's does: the activity
            that leaves a layer across an edge by the cell at the start of that edge, moving
            along one axis only, is dropped (its loops start at 1; the normalisation later
            rescales the rest); 0 = everything wraps around.

    Visual odometry (camera-only inputs; OpenRatSLAM's ``visual_odometry.cpp`` and its names):

    Attributes:
        vtrans_image_x_min, vtrans_image_x_max, vtrans_image_y_min, vtrans_image_y_max: the
            image strip (reference pixels, end exclusive) whose column intensity profile gives
            the speed: the mean absolute difference to the previous frame's profile at the best
            shift, times ``vtrans_scaling``, at most ``vtrans_max`` (m/s).
        vrot_image_x_min, vrot_image_x_max, vrot_image_y_min, vrot_image_y_max: the strip whose
            profile's best shift (at most 40 columns either way) gives the rotation.
        camera_fov_deg: horizontal field of view of the whole image (OpenRatSLAM: 50).
        camera_hz: camera rate that turns a shift per frame into a rate (OpenRatSLAM: 10); 0
            (the default) takes each frame's own interval, so a shift of ``s`` columns is a turn
            of ``s * camera_fov_deg / width`` whatever the rate.
        vtrans_scaling: metres per second per unit of mean profile difference (OpenRatSLAM:
            100).
        vtrans_max: largest speed the visual odometry reports (OpenRatSLAM: 20 m/s).

    """

    reference_image_width: int = 416
    reference_image_height: int = 240
    image_crop_x_min: int = 0
    image_crop_x_max: int = 416
    image_crop_y_min: int = 0
    image_crop_y_max: int = 150
    template_x_size: int = 60
    template_y_size: int = 20
    vt_shift_match: int = 4
    vt_step_match: int = 1
    vt_match_threshold: float = 0.03
    vt_normalisation: float = 0.0
    vt_patch_normalise: int = 0
    vt_min_patch_normalisation_std: float = 0.0
    camera_hfov_deg: float = 0.0
    pc_dim_xy: int = 11
    pc_dim_th: int = 36
    pc_w_e_dim: int = 7
    pc_w_i_dim: int = 5
    pc_w_e_var: float = 1.0
    pc_w_i_var: float = 2.0
    pc_global_inhib: float = 0.00002
    pc_vt_inject_energy: float = 0.1
    pc_cell_x_size: float = 0.015
    pc_vt_restore: float = 0.05
    vt_active_decay: float = 1.0
    vt_recent_no_inject: int = 10
    pc_cells_to_avg: int = 3
    exp_delta_pc_threshold: float = 2.0
    vt_whole_crop: int = 0
    vt_mean_skip: int = 1
    pc_update_per_odometry: int = 1
    pc_inject_nearest: int = 0
    pc_edge_loss: int = 1
    vtrans_image_x_min: int = 0
    vtrans_image_x_max: int = 416
    vtrans_image_y_min: int = 0
    vtrans_image_y_max: int = 240
    vrot_image_x_min: int = 0
    vrot_image_x_max: int = 416
    vrot_image_y_min: int = 0
    vrot_image_y_max: int = 240
    camera_fov_deg: float = 50.0
    camera_hz: float = 0.0
    vtrans_scaling: float = 100.0
    vtrans_max: float = 20.0

    def __post_init__(self) -> None:
        """Reject values outside each parameter's valid range and inconsistent combinations."""
        for f in fields(self):
            _validate_parameter(f.name, getattr(self, f.name))
        self._validate_combinations()

    def _validate_combinations(self) -> None:
        def fail(message: str) -> None:
            raise ParameterError(message)

        if self.image_crop_x_max > self.reference_image_width:
            fail(
                f"image_crop_x_max={self.image_crop_x_max} is out of range: must be in "
                f"(image_crop_x_min, reference_image_width={self.reference_image_width}]"
            )
        if self.image_crop_x_min >= self.image_crop_x_max:
            fail(
                f"image_crop_x_min={self.image_crop_x_min} is out of range: must be in "
                f"[0, image_crop_x_max={self.image_crop_x_max})"
            )
        if self.image_crop_y_max > self.reference_image_height:
            fail(
                f"image_crop_y_max={self.image_crop_y_max} is out of range: must be in "
                f"(image_crop_y_min, reference_image_height={self.reference_image_height}]"
            )
        if self.image_crop_y_min >= self.image_crop_y_max:
            fail(
                f"image_crop_y_min={self.image_crop_y_min} is out of range: must be in "
                f"[0, image_crop_y_max={self.image_crop_y_max})"
            )
        sizes = (("x", self.reference_image_width), ("y", self.reference_image_height))
        for strip in ("vtrans", "vrot"):
            for axis, size in sizes:
                low = getattr(self, f"{strip}_image_{axis}_min")
                high = getattr(self, f"{strip}_image_{axis}_max")
                if not low < high <= size:
                    fail(
                        f"{strip}_image_{axis}_min={low}, {strip}_image_{axis}_max={high} are out "
                        f"of range: need 0 <= min < max <= {size} (the reference image)"
                    )
        if 2 * self.vt_shift_match >= self.template_x_size:
            fail(
                f"vt_shift_match={self.vt_shift_match} is out of range: must be in "
                f"[0, {(self.template_x_size - 1) // 2}] (less than half of template_x_size)"
            )
        for name in ("pc_w_e_dim", "pc_w_i_dim"):
            dim = getattr(self, name)
            if dim % 2 == 0 or dim > min(self.pc_dim_xy, self.pc_dim_th):
                fail(
                    f"{name}={dim} is out of range: must be odd and in "
                    f"[1, {min(self.pc_dim_xy, self.pc_dim_th)}] (at most pc_dim_xy and pc_dim_th)"
                )
        if 2 * self.pc_cells_to_avg + 1 > min(self.pc_dim_xy, self.pc_dim_th):
            fail(
                f"pc_cells_to_avg={self.pc_cells_to_avg} is out of range: must be in "
                f"[0, {(min(self.pc_dim_xy, self.pc_dim_th) - 1) // 2}]"
            )

    @property
    def shifts(self) -> tuple[int, ...]:
        """Template offsets tried by the matcher: ``0, step, ..., 2 * vt_shift_match``."""
        return tuple(range(0, 2 * self.vt_shift_match + 1, self.vt_step_match))

    def minimum_image_size(self, scale: int = 1) -> tuple[int, int]:
        """Smallest camera image ``(width, height)`` whose crop covers the template pixel for pixel.

        Smaller images would be magnified into the template and give meaningless views. With
        ``scale`` the size is that of the recorded image decoded at ``1/scale``.
        """
        crop_x = (self.image_crop_x_max - self.image_crop_x_min) / self.reference_image_width
        crop_y = (self.image_crop_y_max - self.image_crop_y_min) / self.reference_image_height
        width = math.ceil(self.template_x_size / crop_x - 1e-9)
        height = math.ceil(self.template_y_size / crop_y - 1e-9)
        return width * scale, height * scale

    def with_changes(self, **changes: float) -> FrontEndConfig:
        """Return a copy with some parameters changed (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ParameterError(
                f"unknown front-end parameter(s) {sorted(unknown)}; "
                f"known: {[f.name for f in fields(self)]}"
            )
        return replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        """Plain dict of all parameters (for JSON)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> FrontEndConfig:
        """Build from a dict such as :meth:`to_dict` wrote; unknown keys are an error."""
        return cls().with_changes(**values)


def parameter_range(name: str) -> tuple[float, bool, float, bool]:
    """Return the valid range of a front-end parameter: (lower, lower incl., upper, upper incl.)."""
    low, low_inc, high, high_inc, _, _ = _RANGES[name]
    return low, low_inc, high, high_inc


def _validate_parameter(name: str, value: object) -> None:
    """Raise :class:`ParameterError` (naming the valid range) if ``value`` is out of range."""
    low, low_inc, high, high_inc, integer, meaning = _RANGES[name]
    if integer:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = is_finite_number(value)
    if ok:
        v = float(value)  # type: ignore[arg-type]
        ok = (v >= low if low_inc else v > low) and (v <= high if high_inc else v < high)
    if not ok:
        kind = "an integer" if integer else "a number"
        lb = "[" if low_inc else "("
        rb = "]" if high_inc else ")"
        raise ParameterError(
            f"{name}={short_repr(value)} is out of range: {meaning} must be {kind} in "
            f"{lb}{low:g}, {high:g}{rb}"
        )
