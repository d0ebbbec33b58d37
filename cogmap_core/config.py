"""Typed, validated parameters of the cognitive map (paper values as defaults)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from cogmap_core.edge_noise import OdometryNoise
from cogmap_core.errors import ParameterError
from cogmap_core.parameter_table import MAP_PARAMETERS
from cogmap_core.robust import MAP_IRLS_TOLERANCE, LoopClosureModel, loop_closure_model

# name -> (lower bound, lower bound inclusive?, upper bound, meaning); upper bound inclusive.
_RANGES: dict[str, tuple[float, bool, float, str]] = {
    p.name: (*p.valid, p.meaning) for p in MAP_PARAMETERS
}
_WHOLE_NUMBERS = frozenset(p.name for p in MAP_PARAMETERS if p.whole_number)
"""Parameters that are codes: only whole numbers are valid."""


@dataclass(frozen=True, slots=True)
class MapParams:
    """Parameters of the cognitive map.

    Defaults are the paper's: alpha = beta = 10, delta = 3.746, T_interval = 2 s,
    T_total = 100 s, Huber loss. The remaining ones the paper leaves open; the defaults suit
    iRat-scale mazes (0.3 m corridors); docs/maps.md gives the measurements behind them.

    Attributes:
        alpha: translation weight of the neighborhood field
            g(d, theta) = (1 + alpha d)(1 + beta |theta|).
        beta: rotation weight of the neighborhood field.
        delta: threshold; a proposed vertex is added only when g > delta (must be > 1, since
            g >= 1).
        t_interval: a loop-closure edge joins the open cluster only if it comes less than
            ``t_interval`` seconds after the previous loop-closure edge.
        t_total: ... and no more than ``t_total`` seconds after the cluster's first edge.
        huber_scale: scale of the Huber loss on every edge residual.
        short_edge_threshold: after optimisation, edges shorter than this are contracted.
        integration_radius: scene integration merges a revisit run only when each of its
            vertices lies within this distance of an edge of known ground
            (:mod:`~cogmap_core.scene_integration`). Routes take two vertices this close for
            one place and join them (:mod:`~cogmap_core.routes`).
        integration_max_residual: ... and the run's closing loop-closure link agrees with the
            map: its residual, weighed as the optimiser weighs it, is at most this.
        integration_min_age: known ground is what the map had at least this many seconds
            before the run began (a link to a vertex the robot just made ends no run).
        gate_position: a relocalisation (link + set current) is followed only when the pose it
            claims is within this distance of the robot's pose in the map, plus
            ``gate_drift_position`` per metre of map path between them
            (:mod:`~cogmap_core.relocalisation`); 1e9 follows every one (the paper).
        gate_heading: ... and its heading within this, plus ``gate_drift_heading`` per metre
            and the latest frame's rotation.
        gate_drift_position: position drift of odometry allowed per metre of path (m/m).
        gate_drift_heading: heading drift of odometry allowed per metre of path (rad/m).
        gate_consensus: this many refused relocalisations in a row that agree with each other
            are followed after all (the map's own estimate was off); 0 never.
        edge_noise_model: 1 weighs each edge's residual by its expected precision
            (:mod:`~cogmap_core.edge_noise`); 0 gives every residual the same weight (the
            paper's formulation).
        link_sigma_position: with the noise model, the position precision of a loop-closure
            link (standard deviation, m): how well the front end places the robot at the place
            it recognised. Loop closures keep unit weight and odometry is weighed relative to
            them, so the Huber scale reads in metres of loop-closure error. Routes are
            straightened within this distance of their vertices (:mod:`~cogmap_core.routes`).
        link_sigma_heading: ... and its heading precision (rad).
        loop_model: how the batch optimisation judges loop closures
            (:data:`~cogmap_core.robust.LOOP_MODELS`): 0 the paper's Huber loss on every
            edge; 1 Cauchy, 2 Geman-McClure (switchable constraints), 3 dynamic covariance
            scaling, 4 max-mixture, 5 graduated Geman-McClure on the loop closures, the other
            edges keeping the Huber loss. Default 2, measured against the others in
            ``benchmarks/robust.py`` (bags, generated logs, real data, pose graphs).
        loop_scale: the robust loop-closure model's kernel scale, in standard deviations of a
            link (``link_sigma_position``). Default 3: a link is rejected past a chi^2 of 9,
            which a true link's 3-DOF whitened error exceeds 3 % of the time. Measured: at 1
            and 2 sigmas true links are rejected on bags (``long_corridors`` fidelity 0.66 and
            0.99) and at 1 sigma on Lecture Hall (scene-integration correctness 0.91); at 3
            and 4 every bag figure stays within 5 % of the paper's Huber
            (``docs/maps.md``).
        odometry_scale: with the noise model, the factor on the odometry edges' sigmas. 1 for
            camera inputs; a log's default is measured from its own loop candidates
            (:mod:`~cogmap_core.odometry_scale`: 0.3-1, ``LogReader.map_params``).
        odometry_step_length: with the noise model, the length of the odometry steps the map's
            edges are made of (m): an edge replacing several steps (the compact map's, which
            declined the vertices between) weighs as that chain of steps
            (:class:`~cogmap_core.edge_noise.OdometryNoise`). 0 (camera inputs): every edge is
            one step. A log's is its vertex step (``LogReader.map_params``).
        odometry_step_turn: ... and their turn (rad); a log's vertex turn.
        short_edge_loops: 1 (the paper, camera inputs): short-edge removal contracts a loop
            closure whose two ends the optimisation brought together, like any edge; 0 (a
            log's default): never, so that the loop model can still reject the link at a later
            optimisation (:mod:`~cogmap_core.short_edges`).
        integration_keeps_evidence: 1 (default): the scene-integration map keeps what a merged
            revisit run measured -- its chain of edges, marginalised onto the run's two ends
            (:mod:`~cogmap_core.marginalisation`) -- instead of dropping it; 0: the paper's
            merge. Measured on 12 bags and the generated and real logs (``docs/maps.md``).

    """

    alpha: float = 10.0
    beta: float = 10.0
    delta: float = 3.746
    t_interval: float = 2.0
    t_total: float = 100.0
    huber_scale: float = 0.1
    short_edge_threshold: float = 0.03
    integration_radius: float = 0.1
    integration_max_residual: float = 0.1
    integration_min_age: float = 10.0
    gate_position: float = 0.1
    gate_heading: float = 0.17
    gate_drift_position: float = 0.05
    gate_drift_heading: float = 0.02
    gate_consensus: float = 8.0
    edge_noise_model: float = 1.0
    link_sigma_position: float = 0.03
    link_sigma_heading: float = 0.1
    loop_model: float = 2.0
    loop_scale: float = 3.0
    odometry_scale: float = 1.0
    odometry_step_length: float = 0.0
    odometry_step_turn: float = 0.0
    short_edge_loops: float = 1.0
    integration_keeps_evidence: float = 1.0

    def __post_init__(self) -> None:
        """Reject values outside each parameter's valid range."""
        for f in fields(self):
            validate_parameter(f.name, getattr(self, f.name))

    def with_changes(self, **changes: float) -> MapParams:
        """Return a copy with some parameters changed (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ParameterError(
                f"unknown map parameter(s) {sorted(unknown)}; "
                f"known: {[f.name for f in fields(self)]}"
            )
        return replace(self, **changes)

    def link_sigmas(self) -> tuple[float, float] | None:
        """The loop-closure precision edges are weighed against; None for identity weights."""
        if self.edge_noise_model < 0.5:
            return None
        return self.link_sigma_position, self.link_sigma_heading

    def odometry_noise(self) -> OdometryNoise:
        """How the odometry edges are weighed beyond the model's rates (scale, steps)."""
        return OdometryNoise(
            self.odometry_scale, self.odometry_step_length, self.odometry_step_turn
        )

    def loop_closure_model(self) -> LoopClosureModel | None:
        """The robust loop-closure model the optimisation uses; None for the paper's Huber."""
        # loop closures keep unit weight (edge_noise), so their whitened residual reads in
        # metres: a scale of loop_scale link sigmas is loop_scale x link_sigma_position metres
        scale = self.loop_scale * self.link_sigma_position
        return loop_closure_model(int(self.loop_model), scale, MAP_IRLS_TOLERANCE)

    def to_dict(self) -> dict[str, float]:
        """Plain dict of all parameters (for JSON)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> MapParams:
        """Build from a dict, ignoring nothing: unknown keys are an error."""
        return cls().with_changes(**values)


def parameter_range(name: str) -> tuple[float, bool, float]:
    """Valid range of a map parameter: (lower, lower inclusive, upper)."""
    low, inclusive, high, _ = _RANGES[name]
    return low, inclusive, high


def validate_parameter(name: str, value: float) -> None:
    """Raise :class:`ParameterError` (naming the valid range) if ``value`` is out of range."""
    low, inclusive, high, meaning = _RANGES[name]
    ok = is_finite_number(value)
    if ok:
        ok = (value >= low if inclusive else value > low) and value <= high
    if ok and name in _WHOLE_NUMBERS:
        ok = float(value).is_integer()
    if not ok:
        bracket = "[" if inclusive else "("
        wrong = (
            "is not a number"
            if not isinstance(value, int | float) or isinstance(value, bool)
            else "is out of range"
        )
        raise ParameterError(
            f"{name}={short_repr(value)} {wrong}: {meaning} must be in {bracket}{low:g}, {high:g}]"
        )


def is_finite_number(value: object) -> bool:
    """Whether ``value`` is an int or float (not a bool) that is finite as a float.

    ``true`` in a JSON file is not 1, and an integer too large for a float (400 digits) is not
    a number either (``math.isfinite`` would raise OverflowError on it).
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def short_repr(value: object, limit: int = 40) -> str:
    """``repr(value)``, cut to about ``limit`` characters (a 400-digit integer stays one line)."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[: limit - 10]}… ({len(text)} characters)"
