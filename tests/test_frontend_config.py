"""FrontEndConfig: iRat defaults, serialisation, range validation."""

from __future__ import annotations

import json

import pytest

from cogmap_core.errors import ParameterError
from cogmap_core.frontend import FrontEndConfig


def test_defaults_are_the_irat_values() -> None:
    c = FrontEndConfig()
    # config_irataus.txt
    assert (c.image_crop_y_min, c.image_crop_y_max) == (0, 150)
    assert (c.template_x_size, c.template_y_size) == (60, 20)
    assert (c.vt_shift_match, c.vt_step_match, c.vt_match_threshold) == (4, 1, 0.03)
    assert c.vt_active_decay == 1.0
    assert (c.pc_dim_xy, c.pc_vt_inject_energy, c.pc_cell_x_size) == (11, 0.1, 0.015)
    assert c.exp_delta_pc_threshold == 2.0
    # OpenRatSLAM defaults the iRat file leaves alone
    assert (c.pc_dim_th, c.pc_w_e_dim, c.pc_w_i_dim) == (36, 7, 5)
    assert (c.pc_w_e_var, c.pc_w_i_var, c.pc_global_inhib) == (1.0, 2.0, 0.00002)
    assert (c.pc_vt_restore, c.vt_patch_normalise, c.vt_normalisation) == (0.05, 0, 0.0)
    assert (c.reference_image_width, c.reference_image_height) == (416, 240)
    assert c.shifts == tuple(range(9))


def test_round_trips_through_json() -> None:
    c = FrontEndConfig(vt_match_threshold=0.05, pc_dim_xy=21, camera_hfov_deg=70.0)
    d = json.loads(json.dumps(c.to_dict()))
    assert FrontEndConfig.from_dict(d) == c
    assert FrontEndConfig.from_dict({}) == FrontEndConfig()


def test_with_changes_validates() -> None:
    c = FrontEndConfig().with_changes(vt_shift_match=2)
    assert c.shifts == (0, 1, 2, 3, 4)
    with pytest.raises(ParameterError, match="unknown front-end parameter"):
        FrontEndConfig().with_changes(no_such_thing=1)
    with pytest.raises(ParameterError, match="unknown"):
        FrontEndConfig.from_dict({"alpha": 1.0})


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("vt_match_threshold", -0.01, r"vt_match_threshold=-0.01 is out of range: .* \[0, 1\]"),
        ("vt_match_threshold", float("nan"), "out of range"),
        ("pc_cell_x_size", 0.0, r"must be a number in \(0, 1000\]"),
        ("pc_dim_xy", 2, r"must be an integer in \[3, 1000\]"),
        ("pc_dim_xy", 11.0, "must be an integer"),
        ("pc_dim_xy", True, "must be an integer"),
        ("vt_step_match", 0, r"\[1, 999\]"),
        ("pc_global_inhib", 1.0, r"\[0, 1\)"),
        ("template_x_size", "60", "must be an integer"),
    ],
)
def test_out_of_range_values_are_rejected_with_the_range(
    name: str, value: object, message: str
) -> None:
    with pytest.raises(ParameterError, match=message):
        FrontEndConfig(**{name: value})  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"image_crop_y_max": 300}, r"image_crop_y_max=300 .* reference_image_height=240"),
        ({"image_crop_x_min": 416}, r"image_crop_x_min=416 .* \[0, image_crop_x_max=416\)"),
        ({"image_crop_y_min": 150}, "image_crop_y_min=150"),
        ({"vt_shift_match": 30}, r"vt_shift_match=30 .* \[0, 29\]"),
        ({"pc_w_e_dim": 6}, "must be odd"),
        ({"pc_w_e_dim": 13}, r"\[1, 11\]"),
        ({"pc_cells_to_avg": 6}, r"pc_cells_to_avg=6 .* \[0, 5\]"),
    ],
)
def test_inconsistent_combinations_are_rejected(changes: dict, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        FrontEndConfig(**changes)


def test_is_frozen() -> None:
    c = FrontEndConfig()
    with pytest.raises(AttributeError):
        c.pc_dim_xy = 21  # type: ignore[misc]
