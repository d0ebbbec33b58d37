"""A log's odometry measured by its own loop candidates (cogmap_core/odometry_scale.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cogmap_core.datasets.log_generator import LogGeneratorConfig, generate_log
from cogmap_core.datasets.log_writer import write_log
from cogmap_core.edge_noise import OdometryNoise, edge_information
from cogmap_core.odometry_scale import (
    MIN_CANDIDATES,
    MIN_SCALE,
    estimate_odometry_scale,
    innovation_ratios,
)
from cogmap_core.sources.detect import KINDS, input_map_params, open_source
from cogmap_core.sources.log_reader import LogReader
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS


def straight(seconds: float, speed: float = 1.0, dt: float = 0.1) -> np.ndarray:
    """Odometry rows (time, v, omega) of a straight drive at ``speed``."""
    times = np.round(np.arange(0.0, seconds + dt / 2, dt), 9)
    return np.column_stack([times, np.full(times.size, speed), np.zeros(times.size)])


def out_and_back(seconds: float, dt: float = 0.1) -> np.ndarray:
    """Forward at 1 m/s for ``seconds``, then backward at 1 m/s to the start."""
    times = np.round(np.arange(0.0, 2 * seconds + dt / 2, dt), 9)
    speed = np.where(times <= seconds + 1e-9, 1.0, -1.0)
    return np.column_stack([times, speed, np.zeros(times.size)])


def test_the_ratio_of_a_straight_drive_is_the_model_s_prediction_worked_out_by_hand() -> None:
    # 10 m straight, 100 steps of 0.1 m: dead reckoning puts the two times 10 m apart
    odometry = straight(10.0)
    ratios = innovation_ratios(odometry, np.array([[10.0, 0.0], [0.5, 0.0]]), 0.5)
    # heading variance per step 0.03^2 x 0.1 m, swung over the 10 - 0.1 k metres still to go
    swing = 0.03**2 * 0.1 * sum((0.1 * m) ** 2 for m in range(100))
    position = 0.05**2 * 10.0  # position variance per metre driven
    link = 0.5**2
    assert ratios.shape == (1,)  # (0.5, 0.0): 5 samples apart, not usable
    assert ratios[0] == pytest.approx(10.0**2 / (2 * (swing + position + link)), rel=1e-12)
    assert ratios[0] == pytest.approx(87.640115, abs=1e-6)


def test_candidates_that_dead_reckoning_agrees_with_give_the_stiffest_scale() -> None:
    odometry = out_and_back(10.0)
    back_at = [(20.0 - 0.1 * m, 0.1 * m) for m in range(12)]  # the same place, out and back
    estimate = estimate_odometry_scale(odometry, np.array(back_at), 0.5)
    assert estimate.candidates == 12
    assert estimate.median_ratio < 1e-20
    assert estimate.scale == MIN_SCALE


def test_odometry_worse_than_the_model_keeps_the_model_and_few_candidates_say_nothing() -> None:
    odometry = straight(30.0)
    far_apart = np.array([(10.0 + k, k * 0.5) for k in range(MIN_CANDIDATES)])
    estimate = estimate_odometry_scale(odometry, far_apart, 0.5)
    assert estimate.candidates == MIN_CANDIDATES and estimate.median_ratio > 1.0
    assert estimate.scale == 1.0
    few = estimate_odometry_scale(odometry, far_apart[: MIN_CANDIDATES - 1], 0.5)
    assert few.candidates == MIN_CANDIDATES - 1 and few.scale == 1.0
    none = estimate_odometry_scale(odometry, np.zeros((0, 2)), 0.5)
    assert none.candidates == 0 and none.scale == 1.0 and np.isnan(none.median_ratio)


def test_a_ratio_between_the_bounds_gives_its_square_root() -> None:
    odometry = out_and_back(10.0)
    # 0.4 m off the start on the way back: |e|^2 = 0.16; the way there and back is 0.4 m long
    estimate = estimate_odometry_scale(odometry, np.array([[19.6, 0.0]] * MIN_CANDIDATES), 0.5)
    ratio = innovation_ratios(odometry, np.array([[19.6, 0.0]]), 0.5)[0]
    assert MIN_SCALE**2 < ratio < 1.0
    assert estimate.median_ratio == ratio and estimate.scale == pytest.approx(np.sqrt(ratio))


def test_the_odometry_edges_sigmas_are_scaled_and_the_links_kept() -> None:
    kinds = np.array([0, 1, 0], dtype=np.int8)
    rel = np.array([[1.0, 0.0, 0.1], [0.2, 0.1, 0.0], [0.5, 0.0, -0.3]])
    sigmas = (0.5, 0.5)
    plain = edge_information(kinds, rel, sigmas)
    scaled = edge_information(kinds, rel, sigmas, OdometryNoise(scale=0.5))
    np.testing.assert_allclose(scaled[[0, 2]], plain[[0, 2]] / 0.25, rtol=1e-15)
    np.testing.assert_array_equal(scaled[1], plain[1])
    identity = edge_information(kinds, rel, None, OdometryNoise(0.5, 0.2, 0.2))  # no model
    np.testing.assert_array_equal(identity, np.tile(np.eye(3), (3, 1, 1)))


def test_an_edge_of_several_steps_weighs_as_their_chain() -> None:
    kinds = np.array([0, 0, 0, 1], dtype=np.int8)
    rel = np.array([[1.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.1, 0.0, 0.6], [1.0, 0.0, 0.0]])
    sigmas = (0.5, 0.22)
    info = edge_information(kinds, rel, sigmas, OdometryNoise(1.0, 0.2, 0.2))
    # 1 m straight: five steps of 0.2 m, each sigma 0.005 + 0.05 x 0.2 (position),
    # 0.005 + 0.03 x 0.2 (heading); the chain's variance is five times one step's
    assert info[0, 0, 0] == pytest.approx(0.5**2 / (5 * (0.005 + 0.01) ** 2), rel=1e-12)
    assert info[0, 2, 2] == pytest.approx(0.5**2 / (5 * (0.005 + 0.006) ** 2), rel=1e-12)
    one_step = edge_information(kinds, rel, sigmas)  # an edge of one step: as before
    np.testing.assert_allclose(info[1], one_step[1], rtol=1e-12)
    # 0.6 rad turned on 0.1 m: three steps of 0.2 rad
    assert info[2, 2, 2] == pytest.approx(
        0.5**2 / (3 * (0.005 + 0.05 * 0.2 + 0.03 * 0.1 / 3) ** 2), rel=1e-12
    )
    np.testing.assert_array_equal(info[3], one_step[3])  # a link is no chain
    assert one_step[0, 0, 0] == pytest.approx(0.5**2 / (0.005 + 0.05) ** 2, rel=1e-12)


@pytest.mark.parametrize(("drift", "stiffer"), [("medium", True), ("extreme", False)])
def test_a_log_s_defaults_carry_its_own_odometry_scale(
    drift: str, stiffer: bool, tmp_path: Path
) -> None:
    generated = generate_log(LogGeneratorConfig(pattern="loop", seed=1, drift=drift))
    write_log(generated, tmp_path / "loop", "tuc")
    reader = open_source(tmp_path / "loop_Input.txt")
    assert isinstance(reader, LogReader)
    estimate = reader.odometry_scale
    assert estimate.candidates >= MIN_CANDIDATES
    assert (estimate.scale < 1.0) is stiffer and estimate.scale >= MIN_SCALE
    defaults = input_map_params(KINDS["tuc"], reader)
    assert defaults == LOG_MAP_PARAMS.with_changes(odometry_scale=estimate.scale)
    assert (defaults.odometry_step_length, defaults.odometry_step_turn) == (0.2, 0.2)
    assert reader.map_params == defaults
    # the candidates it is measured over are those the map is given
    assert estimate.candidates <= reader.stats.used_loops.shape[0] <= reader.stats.loop_candidates
