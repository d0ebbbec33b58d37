"""Edge weights: loop closures weighed by the front end's link precision, odometry against it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind
from cogmap_core.config import MapParams
from cogmap_core.edge_noise import edge_information
from cogmap_core.errors import ParameterError
from cogmap_core.events import LinkToVertex
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests.mapscript import Script

KINDS = np.array([EdgeKind.SEQUENTIAL, EdgeKind.LOOP_CLOSURE], dtype=np.int8)
RELATIVE = np.array([[0.2, 0.0, 0.1], [0.05, 0.0, 0.0]])


def test_identity_without_the_noise_model() -> None:
    info = edge_information(KINDS, RELATIVE, None)
    np.testing.assert_array_equal(info, np.broadcast_to(np.eye(3), (2, 3, 3)))


@pytest.mark.parametrize(("position", "heading"), [(0.03, 0.1), (0.5, 0.22)])
def test_loop_closures_keep_unit_weight_and_odometry_is_weighed_against_them(
    position: float, heading: float
) -> None:
    info = edge_information(KINDS, RELATIVE, (position, heading))
    # an odometry step of 0.2 m turning 0.1 rad: sigma_xy = 5 mm + 5 % of 0.2 m = 15 mm,
    # sigma_theta = 5 mm rad + 5 % of 0.1 rad + 0.03 rad/m * 0.2 m = 16 mrad
    np.testing.assert_allclose(
        np.diagonal(info[0]), [(position / 0.015) ** 2] * 2 + [(position / 0.016) ** 2]
    )
    np.testing.assert_allclose(np.diagonal(info[1]), [1.0, 1.0, (position / heading) ** 2])
    assert not info[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]].any()


def coarse_return(params: MapParams) -> float:
    """Out 1 m east, back 1 m west 0.4 m further north; a link claims the start is reached.

    Odometry is exact. Returns how far the map puts the last vertex from the first (truly
    0.4 m).
    """
    s = Script()
    s.create()
    for _ in range(5):
        s.drive(0.2, 2)
        s.create()
    s.move(0.0, math.pi / 2)
    s.drive(0.4, 4)
    s.move(0.0, math.pi / 2)
    for _ in range(5):
        s.drive(0.2, 2)
        s.create()
    last = s.next_id - 1
    s.wait(1.0)
    s.events.append(LinkToVertex(s.t, 0, s.rel_to(0)))  # "same place" as 0, heading right
    cmap = CognitiveMap("standard", params)
    cmap.apply_all(s.events)
    cmap.finish()
    first, end = cmap.vertex_pose(0), cmap.vertex_pose(last)
    return math.hypot(*(end[:2] - first[:2]))


def test_a_coarse_link_weighed_by_its_precision_does_not_bend_precise_odometry() -> None:
    no_gate = MapParams(gate_position=1e9, gate_heading=1e9, loop_model=0.0)
    # under the paper's Huber, weighed like RatSLAM's view matching (3 cm), the link drags the
    # return leg onto the start
    assert coarse_return(no_gate) < 0.1
    # weighed like place recognition (0.5 m), the odometry's 0.4 m stands
    assert coarse_return(no_gate.with_changes(link_sigma_position=0.5, huber_scale=0.5)) > 0.3
    # the default robust loop model rejects a 3 cm link 0.4 m off (13 sigmas): odometry stands
    # (the rejected link keeps Geman-McClure's weight (0.09^2 / (0.09^2 + 0.4^2))^2 = 0.002)
    assert 0.35 < coarse_return(no_gate.with_changes(loop_model=2.0)) < 0.4


def test_logs_weigh_links_as_place_recognition_and_bags_as_view_matching() -> None:
    assert LOG_MAP_PARAMS.link_sigmas() == (0.5, 0.22)
    assert LOG_MAP_PARAMS.huber_scale == 0.5
    assert MapParams().link_sigmas() == (0.03, 0.1)
    assert MapParams(edge_noise_model=0.0).link_sigmas() is None


@pytest.mark.parametrize("name", ["link_sigma_position", "link_sigma_heading"])
def test_link_precision_must_be_positive(name: str) -> None:
    with pytest.raises(ParameterError, match=f"{name}=0.0 is out of range"):
        MapParams().with_changes(**{name: 0.0})
