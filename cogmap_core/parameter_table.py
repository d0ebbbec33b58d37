"""The map parameters, one row each: what the code knows about each field of ``MapParams``.

:class:`~cogmap_core.config.MapParams` holds the values (and the defaults); this table holds
everything else about a parameter, once:

- its valid range and meaning (:func:`~cogmap_core.config.validate_parameter` and its messages);
- its short label on the page, its slider there if it has one (range, step, hint, basic or
  advanced panel, place);
- whether the paper fixes it (the five of the paper: alpha, beta, delta, T_interval, T_total);
- whether it is a threshold of the loop-closure clustering (it acts on a map only through the
  cluster schedule, :mod:`cogmap_core.schedule`);
- its dedicated option of ``cogmap run`` / ``cogmap serve`` if it has one (the others are given
  with ``--param NAME=VALUE``);
- which of the three maps it affects (a change of any other parameter leaves a map as it is, so
  the web app does not rebuild it).

Every list of parameters elsewhere is derived from it (the CLI options, the sliders, the paper's
parameters, the maps each parameter affects, ``summary.json``'s parameters), so a new parameter
is a field of ``MapParams`` and a row here. ``tests/test_parameter_table.py`` checks that the
table names every field of ``MapParams`` once, in the same order.
"""

from __future__ import annotations

from dataclasses import dataclass

from cogmap_core.map_modes import ALL_MODES, MapMode


@dataclass(frozen=True, slots=True)
class Slider:
    """A parameter's slider on the page (inside the parameter's valid range).

    Attributes:
        low: the slider's lowest value.
        high: its highest value.
        step: its step.
        hint: the hint the page shows beside it.
        advanced: in the "advanced" folder (True) or among the basic sliders (False).
        place: its place among the sliders (they are shown in increasing ``place``: the basic
            ones, then the advanced ones).

    """

    low: float
    high: float
    step: float
    hint: str
    advanced: bool
    place: int


@dataclass(frozen=True, slots=True)
class MapParameter:
    """One row of the table: one map parameter (module doc).

    Attributes:
        name: the field of :class:`~cogmap_core.config.MapParams`.
        meaning: what it is, as the message of an invalid value says.
        valid: its valid range: (lower bound, lower bound inclusive?, upper bound); the upper
            bound is inclusive.
        maps: the maps it affects.
        whole_number: a code: only whole numbers are valid.
        label: its short name on the page (its slider's label); None where it has none.
        paper: one of the five parameters the paper fixes.
        clustering: a threshold of the loop-closure clustering (acts on a map only through the
            schedule of clusters).
        flag_help: the meaning its dedicated command-line option (:attr:`flag`) shows in the
            help, the valid lower bound appended; None: it has no option of its own.
        slider: its slider on the page; None: it has none.

    """

    name: str
    meaning: str
    valid: tuple[float, bool, float]
    maps: frozenset[MapMode]
    whole_number: bool = False
    label: str | None = None
    paper: bool = False
    clustering: bool = False
    flag_help: str | None = None
    slider: Slider | None = None

    @property
    def flag(self) -> str | None:
        """Its dedicated command-line option (``--t-interval``), None when it has none."""
        return None if self.flag_help is None else flag_name(self.name)

    def lower_bound_text(self) -> str:
        """Its valid lower bound as the help writes it: ``>= 0``, ``> 1``."""
        low, inclusive, _ = self.valid
        return f"{'>=' if inclusive else '>'} {low:g}"


def flag_name(name: str) -> str:
    """The command-line spelling of parameter ``name`` (``t_interval`` -> ``--t-interval``)."""
    return "--" + name.replace("_", "-")


_EVERY_MAP = frozenset(ALL_MODES)
_INTEGRATING = frozenset({MapMode.SCENE_INTEGRATION, MapMode.COMPACT})
_COMPACT = frozenset({MapMode.COMPACT})
_SCENE_INTEGRATION = frozenset({MapMode.SCENE_INTEGRATION})

MAP_PARAMETERS: tuple[MapParameter, ...] = (
    MapParameter(
        name="alpha",
        meaning="weight of translation in the neighborhood field (1/m)",
        valid=(0.0, True, 1e6),
        maps=_COMPACT,
        label="α",
        paper=True,
        flag_help="translation weight",
        slider=Slider(
            low=0.0,
            high=50.0,
            step=0.1,
            hint="translation weight of the neighborhood field (1/m)",
            advanced=False,
            place=0,
        ),
    ),
    MapParameter(
        name="beta",
        meaning="weight of rotation in the neighborhood field (1/rad)",
        valid=(0.0, True, 1e6),
        maps=_COMPACT,
        label="β",
        paper=True,
        flag_help="rotation weight",
        slider=Slider(
            low=0.0,
            high=50.0,
            step=0.1,
            hint="rotation weight of the neighborhood field (1/rad)",
            advanced=False,
            place=1,
        ),
    ),
    MapParameter(
        name="delta",
        meaning="neighborhood field threshold (g > delta adds a vertex)",
        valid=(1.0, False, 1e12),
        maps=_COMPACT,
        label="δ",
        paper=True,
        flag_help="field threshold",
        slider=Slider(
            low=1.05,
            high=30.0,
            step=0.001,
            hint="add a vertex only when g(d, θ) > δ",
            advanced=False,
            place=2,
        ),
    ),
    MapParameter(
        name="t_interval",
        meaning="loop-closure cluster time-interval threshold (s)",
        valid=(0.0, False, 1e9),
        maps=_EVERY_MAP,
        label="T_interval",
        paper=True,
        clustering=True,
        flag_help="cluster interval threshold (s)",
        slider=Slider(
            low=0.1,
            high=20.0,
            step=0.1,
            hint="cluster interval threshold (s)",
            advanced=False,
            place=3,
        ),
    ),
    MapParameter(
        name="t_total",
        meaning="loop-closure cluster total-time threshold (s)",
        valid=(0.0, False, 1e9),
        maps=_EVERY_MAP,
        label="T_total",
        paper=True,
        clustering=True,
        flag_help="cluster total-time threshold (s)",
        slider=Slider(
            low=1.0,
            high=500.0,
            step=1.0,
            hint="cluster total-time threshold (s)",
            advanced=False,
            place=4,
        ),
    ),
    MapParameter(
        name="huber_scale",
        meaning="Huber loss scale of the batch optimisation (m, rad)",
        valid=(0.0, False, 1e9),
        maps=_EVERY_MAP,
        label="Huber scale",
        slider=Slider(
            low=0.01,
            high=2.0,
            step=0.01,
            hint="Huber loss scale (m, rad): odometry edges; "
            "every edge with the paper's loop model",
            advanced=True,
            place=5,
        ),
    ),
    MapParameter(
        name="short_edge_threshold",
        meaning="edges shorter than this are removed (m)",
        valid=(0.0, True, 1e9),
        maps=_COMPACT,
        label="short edge (m)",
        slider=Slider(
            low=0.0,
            high=0.5,
            step=0.005,
            hint="edges shorter are removed",
            advanced=True,
            place=7,
        ),
    ),
    MapParameter(
        name="integration_radius",
        meaning="max distance of a revisit to merge it (m)",
        valid=(0.0, True, 1e9),
        maps=_INTEGRATING,
    ),
    MapParameter(
        name="integration_max_residual",
        meaning="max loop-edge residual to merge a revisit",
        valid=(0.0, True, 1e9),
        maps=_INTEGRATING,
    ),
    MapParameter(
        name="integration_min_age",
        meaning="min age of the vertex a revisit merges into (s)",
        valid=(0.0, True, 1e9),
        maps=_INTEGRATING,
    ),
    MapParameter(
        name="gate_position",
        meaning="relocalisation test: position tolerance (m)",
        valid=(0.0, True, 1e9),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="gate_heading",
        meaning="relocalisation test: heading tolerance (rad)",
        valid=(0.0, True, 1e9),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="gate_drift_position",
        meaning="relocalisation test: position drift per metre",
        valid=(0.0, True, 1e9),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="gate_drift_heading",
        meaning="relocalisation test: heading drift per metre (rad/m)",
        valid=(0.0, True, 1e9),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="gate_consensus",
        meaning="relocalisation test: agreeing refusals that win (0: off)",
        valid=(0.0, True, 1e9),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="edge_noise_model",
        meaning="1: weigh edges by expected precision, 0: identity",
        valid=(0.0, True, 1.0),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="link_sigma_position",
        meaning="position precision of a loop-closure link (m)",
        valid=(0.0, False, 1e6),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="link_sigma_heading",
        meaning="heading precision of a loop-closure link (rad)",
        valid=(0.0, False, 1e6),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="loop_model",
        meaning="robust loop-closure model (0 the paper's Huber; see robust)",
        valid=(0.0, True, 5.0),
        maps=_EVERY_MAP,
        whole_number=True,
    ),
    MapParameter(
        name="loop_scale",
        meaning="scale of the robust loop-closure model (link sigmas)",
        valid=(0.0, False, 1e6),
        maps=_EVERY_MAP,
        label="loop scale",
        slider=Slider(
            low=0.2,
            high=50.0,
            step=0.1,
            hint="robust loop-closure kernel scale (link σ)",
            advanced=True,
            place=6,
        ),
    ),
    MapParameter(
        name="odometry_scale",
        meaning="factor on the odometry edges' sigmas (a log's is measured)",
        valid=(0.0, False, 10.0),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="odometry_step_length",
        meaning="length of the odometry steps an edge is made of (m; 0: one per edge)",
        valid=(0.0, True, 1e6),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="odometry_step_turn",
        meaning="turn of the odometry steps an edge is made of (rad; 0: one per edge)",
        valid=(0.0, True, 1e6),
        maps=_EVERY_MAP,
    ),
    MapParameter(
        name="short_edge_loops",
        meaning="1: short-edge removal contracts loop closures too (the paper); 0: never",
        valid=(0.0, True, 1.0),
        maps=_COMPACT,
        whole_number=True,
    ),
    MapParameter(
        name="integration_keeps_evidence",
        meaning=(
            "1: a merged revisit run's chain is kept, marginalised onto its two ends; "
            "0: dropped (the paper)"
        ),
        valid=(0.0, True, 1.0),
        maps=_SCENE_INTEGRATION,
        whole_number=True,
    ),
)
"""The table (module doc), in the order of the fields of ``MapParams``."""

PARAMETERS: dict[str, MapParameter] = {p.name: p for p in MAP_PARAMETERS}
"""The table's rows by parameter name."""

PAPER_PARAMETERS: tuple[str, ...] = tuple(p.name for p in MAP_PARAMETERS if p.paper)
"""The parameters the paper fixes (alpha = beta = 10, delta = 3.746, 2 s, 100 s)."""

CLUSTERING_PARAMETERS: frozenset[str] = frozenset(p.name for p in MAP_PARAMETERS if p.clustering)
"""The parameters of the loop-closure clustering (the cluster schedule)."""

FLAG_PARAMETERS: tuple[MapParameter, ...] = tuple(p for p in MAP_PARAMETERS if p.flag_help)
"""The parameters with a command-line option of their own, in table order."""


def _slider_place(parameter: MapParameter) -> int:
    return -1 if parameter.slider is None else parameter.slider.place


SLIDER_PARAMETERS: tuple[MapParameter, ...] = tuple(
    sorted((p for p in MAP_PARAMETERS if p.slider is not None), key=_slider_place)
)
"""The parameters with a slider, in the page's order (basic ones first)."""

PARAMETERS_USED: dict[MapMode, frozenset[str]] = {
    mode: frozenset(p.name for p in MAP_PARAMETERS if mode in p.maps) for mode in ALL_MODES
}
"""The map parameters each map depends on (the neighborhood field and short-edge removal belong
to the compact map only, scene integration to the two non-standard maps, the compact map depends
on every parameter)."""

__all__ = [
    "CLUSTERING_PARAMETERS",
    "FLAG_PARAMETERS",
    "MAP_PARAMETERS",
    "PAPER_PARAMETERS",
    "PARAMETERS",
    "PARAMETERS_USED",
    "SLIDER_PARAMETERS",
    "MapParameter",
    "Slider",
    "flag_name",
]
