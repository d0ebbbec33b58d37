"""The table of map parameters (cogmap_core/parameter_table.py) and every list derived from it.

The expected values are written out: they are what the lists were when each was written by hand,
so a change of the table that changes one of them fails here.
"""

from __future__ import annotations

import argparse
import re
from dataclasses import fields
from pathlib import Path

import pytest

import app.cli_common as cli_common
import app.server.app as server_app
import app.server.replay as replay
from app.server.panels.layers import MODE_NAMES
from app.server.params import ADVANCED_SLIDERS, ALL_SLIDERS, SLIDERS, SliderSpec, check_spec
from app.server.replay_rebuilds import PARAMS_USED
from app.summary import MAP_ORDER
from cogmap_core import config, slam, sweep
from cogmap_core.cognitive_map import MapMode, MapSet
from cogmap_core.config import MapParams
from cogmap_core.errors import ParameterError
from cogmap_core.map_modes import ALL_MODES
from cogmap_core.parameter_table import (
    CLUSTERING_PARAMETERS,
    MAP_PARAMETERS,
    PAPER_PARAMETERS,
    PARAMETERS,
    PARAMETERS_USED,
    flag_name,
)
from cogmap_core.schedule import SCHEDULE_PARAMS

ROOT = Path(__file__).resolve().parents[1]
PAPER = ("alpha", "beta", "delta", "t_interval", "t_total")


def test_the_table_names_every_map_parameter_once_in_order():
    names = [p.name for p in MAP_PARAMETERS]
    assert len(names) == len(set(names))
    assert names == [f.name for f in fields(MapParams)]
    assert list(PARAMETERS) == names
    assert sweep.PARAMETER_NAMES == tuple(names)


def test_every_row_is_consistent():
    places = [p.slider.place for p in MAP_PARAMETERS if p.slider is not None]
    assert sorted(places) == list(range(len(places)))
    for p in MAP_PARAMETERS:
        low, _, high = p.valid
        assert low < high, p.name
        assert p.maps and p.maps <= set(ALL_MODES), p.name
        # the compact map depends on every parameter but the scene-integration map's own
        assert (MapMode.COMPACT in p.maps) != (p.name == "integration_keeps_evidence"), p.name
        if p.slider is not None:
            assert p.label, p.name
            assert p.slider.low < p.slider.high and p.slider.step > 0, p.name
        if p.clustering:
            assert p.maps == set(ALL_MODES), p.name
    for spec in ALL_SLIDERS:
        check_spec(spec)  # each slider's range lies inside its parameter's valid range


def test_the_valid_ranges_and_meanings_are_as_before():
    assert config._RANGES == {
        "alpha": (0.0, True, 1e6, "weight of translation in the neighborhood field (1/m)"),
        "beta": (0.0, True, 1e6, "weight of rotation in the neighborhood field (1/rad)"),
        "delta": (1.0, False, 1e12, "neighborhood field threshold (g > delta adds a vertex)"),
        "t_interval": (0.0, False, 1e9, "loop-closure cluster time-interval threshold (s)"),
        "t_total": (0.0, False, 1e9, "loop-closure cluster total-time threshold (s)"),
        "huber_scale": (0.0, False, 1e9, "Huber loss scale of the batch optimisation (m, rad)"),
        "short_edge_threshold": (0.0, True, 1e9, "edges shorter than this are removed (m)"),
        "integration_radius": (0.0, True, 1e9, "max distance of a revisit to merge it (m)"),
        "integration_max_residual": (0.0, True, 1e9, "max loop-edge residual to merge a revisit"),
        "integration_min_age": (0.0, True, 1e9, "min age of the vertex a revisit merges into (s)"),
        "gate_position": (0.0, True, 1e9, "relocalisation test: position tolerance (m)"),
        "gate_heading": (0.0, True, 1e9, "relocalisation test: heading tolerance (rad)"),
        "gate_drift_position": (0.0, True, 1e9, "relocalisation test: position drift per metre"),
        "gate_drift_heading": (
            0.0,
            True,
            1e9,
            "relocalisation test: heading drift per metre (rad/m)",
        ),
        "gate_consensus": (
            0.0,
            True,
            1e9,
            "relocalisation test: agreeing refusals that win (0: off)",
        ),
        "edge_noise_model": (0.0, True, 1.0, "1: weigh edges by expected precision, 0: identity"),
        "link_sigma_position": (0.0, False, 1e6, "position precision of a loop-closure link (m)"),
        "link_sigma_heading": (0.0, False, 1e6, "heading precision of a loop-closure link (rad)"),
        "loop_model": (
            0.0,
            True,
            5.0,
            "robust loop-closure model (0 the paper's Huber; see robust)",
        ),
        "loop_scale": (0.0, False, 1e6, "scale of the robust loop-closure model (link sigmas)"),
        "odometry_scale": (
            0.0,
            False,
            10.0,
            "factor on the odometry edges' sigmas (a log's is measured)",
        ),
        "odometry_step_length": (
            0.0,
            True,
            1e6,
            "length of the odometry steps an edge is made of (m; 0: one per edge)",
        ),
        "odometry_step_turn": (
            0.0,
            True,
            1e6,
            "turn of the odometry steps an edge is made of (rad; 0: one per edge)",
        ),
        "short_edge_loops": (
            0.0,
            True,
            1.0,
            "1: short-edge removal contracts loop closures too (the paper); 0: never",
        ),
        "integration_keeps_evidence": (
            0.0,
            True,
            1.0,
            "1: a merged revisit run's chain is kept, marginalised onto its two ends; "
            "0: dropped (the paper)",
        ),
    }
    assert config._WHOLE_NUMBERS == {"loop_model", "short_edge_loops", "integration_keeps_evidence"}
    assert config.parameter_range("delta") == (1.0, False, 1e12)
    with pytest.raises(ParameterError, match=r"^loop_model=1\.5 is out of range: robust"):
        MapParams(loop_model=1.5)


def test_the_command_line_options_are_as_before():
    assert cli_common._MAP_ARGUMENTS == (
        ("alpha", "--alpha", "translation weight, >= 0"),
        ("beta", "--beta", "rotation weight, >= 0"),
        ("delta", "--delta", "field threshold, > 1"),
        ("t_interval", "--t-interval", "cluster interval threshold (s), > 0"),
        ("t_total", "--t-total", "cluster total-time threshold (s), > 0"),
    )
    assert cli_common._PAPER_FLAGS == PAPER
    assert [PARAMETERS[n].flag for n in PAPER] == [
        "--alpha",
        "--beta",
        "--delta",
        "--t-interval",
        "--t-total",
    ]
    assert all(p.flag is None for p in MAP_PARAMETERS if p.name not in PAPER)
    assert flag_name("short_edge_threshold") == "--short-edge-threshold"
    parser = argparse.ArgumentParser()
    cli_common.add_map_arguments(parser)
    with pytest.raises(ParameterError, match=r"^--param t_total: use --t-total instead$"):
        cli_common.map_changes_from_args(parser.parse_args(["--param", "t-total=5"]))


def test_the_sliders_are_as_before():
    assert SLIDERS == (
        SliderSpec(
            "α", "alpha", 0.0, 50.0, 0.1, "translation weight of the neighborhood field (1/m)"
        ),
        SliderSpec(
            "β", "beta", 0.0, 50.0, 0.1, "rotation weight of the neighborhood field (1/rad)"
        ),
        SliderSpec("δ", "delta", 1.05, 30.0, 0.001, "add a vertex only when g(d, θ) > δ"),
        SliderSpec("T_interval", "t_interval", 0.1, 20.0, 0.1, "cluster interval threshold (s)"),
        SliderSpec("T_total", "t_total", 1.0, 500.0, 1.0, "cluster total-time threshold (s)"),
    )
    assert ADVANCED_SLIDERS == (
        SliderSpec(
            "Huber scale",
            "huber_scale",
            0.01,
            2.0,
            0.01,
            "Huber loss scale (m, rad): odometry edges; every edge with the paper's loop model",
        ),
        SliderSpec(
            "loop scale", "loop_scale", 0.2, 50.0, 0.1, "robust loop-closure kernel scale (link σ)"
        ),
        SliderSpec(
            "short edge (m)", "short_edge_threshold", 0.0, 0.5, 0.005, "edges shorter are removed"
        ),
    )
    assert server_app.SLIDERS is SLIDERS and server_app.ADVANCED_SLIDERS is ADVANCED_SLIDERS


def test_the_paper_parameters_are_as_before():
    assert PAPER_PARAMETERS == PAPER
    assert sweep.PAPER_PARAMETERS == PAPER


def test_the_maps_each_parameter_affects_are_as_before():
    clustering_and_optimisation = {
        "t_interval",
        "t_total",
        "huber_scale",
        "edge_noise_model",
        "link_sigma_position",
        "link_sigma_heading",
        "gate_position",
        "gate_heading",
        "gate_drift_position",
        "gate_drift_heading",
        "gate_consensus",
        "loop_model",
        "loop_scale",
        "odometry_scale",
        "odometry_step_length",
        "odometry_step_turn",
    }
    integration = {"integration_radius", "integration_max_residual", "integration_min_age"}
    assert PARAMS_USED == {
        MapMode.STANDARD: clustering_and_optimisation,
        MapMode.SCENE_INTEGRATION: clustering_and_optimisation
        | integration
        | {"integration_keeps_evidence"},
        MapMode.COMPACT: set(MapParams().to_dict()) - {"integration_keeps_evidence"},
    }
    assert list(PARAMS_USED) == list(ALL_MODES)
    assert PARAMS_USED is PARAMETERS_USED and replay.PARAMS_USED is PARAMETERS_USED
    assert SCHEDULE_PARAMS == {"t_interval", "t_total"} == CLUSTERING_PARAMETERS


def test_one_tuple_of_the_three_maps():
    assert ALL_MODES == (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)
    assert slam.ALL_MODES is ALL_MODES and MAP_ORDER is ALL_MODES
    assert MODE_NAMES == ("standard", "scene_integration", "compact")
    assert tuple(MapSet().maps) == ALL_MODES
    spelled = re.compile(
        r"\(\s*MapMode\.STANDARD,\s*MapMode\.SCENE_INTEGRATION,\s*MapMode\.COMPACT"
    )
    for package in ("app", "cogmap_core", "benchmarks"):
        for path in (ROOT / package).rglob("*.py"):
            assert not spelled.search(path.read_text(encoding="utf-8")), path
