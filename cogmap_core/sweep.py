"""Parameter sweeps of the cognitive map: what each setting keeps and what it costs.

The pure parts of ``cogmap sweep`` (no I/O): parsing a sweep specification into the settings
to try, building and measuring one map from recorded front-end events, and the Pareto fronts of
size against accuracy and layout fidelity.

**Specifications.** Every map parameter of :class:`~cogmap_core.config.MapParams` can be swept.
A parameter's values are written as

- ``LOW:HIGH:COUNT`` -- ``COUNT`` values from ``LOW`` to ``HIGH`` inclusive, evenly spaced
  (``numpy.linspace``; ``2:8:13`` is 2, 2.5, ..., 8); ``LOW:HIGH:COUNT:log`` spaces them
  geometrically (``numpy.geomspace``);
- ``A,B,C`` -- a list;
- ``A`` -- a single value (the parameter is fixed for the whole sweep).

A *grid* tries every combination. A *random search* (``samples`` settings drawn with ``seed``)
draws each parameter uniformly: from ``LOW:HIGH`` (continuous; ``LOW:HIGH:log`` log-uniform),
or from the values of a list or a ``LOW:HIGH:COUNT`` range. Parameters not named keep their
defaults (the paper's values).

**One cell** (:func:`evaluate_cell`) builds one map from the events with one setting, runs the
end-of-data optimisation and returns its figures (:data:`FIGURE_COLUMNS`): vertices, edges, loop
edges, clusters, optimisations and their time, ATE, layout completeness and correctness, and the
size change over the last part of the run. A bag has no lap times in general, so the size
change is taken over the second half of the data (:data:`GROWTH_FRACTION`): from the middle of
the run to its end, with the vertices made on ground first explored in that half set apart
(``size_change``; ``size_change_raw`` counts them too).

**Fronts.** A setting is on the Pareto front of (vertices, ATE) when no other setting has at most
as many vertices and at most its ATE, and fewer of one or a lower other; likewise (vertices,
completeness) with completeness to maximise. Over several bags a setting's figures are combined
(:func:`aggregate_settings`): vertices, edges and ATE averaged, completeness and correctness the
worst over the bags.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from itertools import product
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.compiled_replay import replay
from cogmap_core.config import MapParams, validate_parameter
from cogmap_core.errors import ParameterError
from cogmap_core.evaluation import LAYOUT_RADIUS
from cogmap_core.event_log import EventLog
from cogmap_core.parameter_table import PAPER_PARAMETERS  # the five the paper fixes
from cogmap_core.slam import optimisation_summary

PARAMETER_NAMES: tuple[str, ...] = tuple(f.name for f in fields(MapParams))
"""Every sweepable parameter, in :class:`MapParams` order."""

GROWTH_FRACTION = 0.5
"""The size change is measured over this last fraction of the data (the second half)."""

MIN_COMPLETENESS = 0.98
"""Completeness the "smallest complete map" of a sweep must reach."""

MAX_CELLS = 100_000
"""Largest number of settings one sweep may have (a guard against a mistyped count)."""

FIGURE_COLUMNS: tuple[str, ...] = (
    "vertices",
    "edges",
    "loop_edges",
    "clusters",
    "optimizations",
    "ate_m",
    "completeness",
    "correctness",
    "size_change",
    "size_change_raw",
    "exploration_vertices",
)
"""Figures of one cell that depend only on the events and the setting (identical on any run)."""

TIMING_COLUMNS: tuple[str, ...] = ("optimize_wall_s", "build_wall_s", "evaluate_wall_s")
"""Wall times of one cell (the only figures that differ between runs)."""


def normalise_parameter_name(text: str) -> str:
    """A map parameter's name as a user wrote it, in :class:`MapParams` spelling (unchecked).

    Surrounding spaces are dropped, dashes become underscores and letters lower case:
    ``t-interval``, ``T_Interval`` and ``t_interval`` (spaces around it or not) are all
    ``t_interval``. The one spelling rule of sweep specs (:func:`parameter_name`) and of
    ``--param NAME=VALUE``.
    """
    return text.strip().replace("-", "_").lower()


def parameter_name(text: str) -> str:
    """The :class:`MapParams` field a user wrote (see :func:`normalise_parameter_name`).

    Raises:
        ParameterError: not a map parameter (the message lists the known ones).

    """
    name = normalise_parameter_name(text)
    if name not in PARAMETER_NAMES:
        raise ParameterError(f"unknown map parameter {text!r}; known: {', '.join(PARAMETER_NAMES)}")
    return name


@dataclass(frozen=True, slots=True)
class ParameterSpec:
    """The values one parameter takes in a sweep.

    Attributes:
        name: the :class:`MapParams` field.
        text: the specification as written.
        values: the values of a grid (or the choices of a random search); empty for a
            continuous range.
        low: lower end of a continuous range (random search only), else ``None``.
        high: upper end of a continuous range.
        log: the range is spaced (or drawn) on a log scale.

    """

    name: str
    text: str
    values: tuple[float, ...] = ()
    low: float | None = None
    high: float | None = None
    log: bool = False

    @property
    def continuous(self) -> bool:
        """True for a ``LOW:HIGH`` range (drawn uniformly, random search only)."""
        return not self.values

    def to_dict(self) -> dict[str, Any]:
        """JSON form (the text and what it means)."""
        if self.continuous:
            return {"text": self.text, "low": self.low, "high": self.high, "log": self.log}
        return {"text": self.text, "values": list(self.values)}


def _number(name: str, text: str, item: str) -> float:
    try:
        value = float(item)
    except ValueError:
        raise ParameterError(
            f"{name} {text!r}: {item.strip()!r} is not a number; write LOW:HIGH:COUNT, "
            "A,B,C or a single value"
        ) from None
    validate_parameter(name, value)
    return value


def parse_parameter(name: str, text: str | float | Sequence[float], random: bool) -> ParameterSpec:
    """Parse one parameter's values (see the module docstring for the syntax).

    Args:
        name: the parameter (``delta``, ``t-interval``, ...).
        text: its specification: a string, a number or a list of numbers (from a spec file).
        random: the sweep is a random search (allows continuous ``LOW:HIGH`` ranges).

    Raises:
        ParameterError: unknown parameter, malformed, empty or inverted range, repeated values,
            or a value outside the parameter's valid range (one line naming the problem).

    """
    name = parameter_name(name)
    if isinstance(text, bool):
        raise ParameterError(f"{name}: {text!r} is not a number")
    if isinstance(text, int | float):
        return ParameterSpec(name, repr(text), (_number(name, repr(text), repr(text)),))
    if not isinstance(text, str):
        items = list(text)
        if not items:
            raise ParameterError(f"{name}: empty list of values; give at least one")
        text = ",".join(repr(v) if isinstance(v, int | float) else str(v) for v in items)
    spec = text.strip()
    if not spec:
        raise ParameterError(f"{name}: no values given; write LOW:HIGH:COUNT, A,B,C or a value")
    if ":" in spec:
        return _parse_range(name, spec, random)
    values = tuple(_number(name, spec, item) for item in spec.split(","))
    if len(set(values)) != len(values):
        raise ParameterError(f"{name} {spec!r}: a value is repeated; list each value once")
    return ParameterSpec(name, spec, values)


def _parse_range(name: str, spec: str, random: bool) -> ParameterSpec:
    parts = [p.strip() for p in spec.split(":")]
    log = parts[-1].lower() == "log"
    if log:
        parts = parts[:-1]
    if len(parts) not in (2, 3):
        raise ParameterError(
            f"{name} {spec!r}: write LOW:HIGH:COUNT (e.g. 2:8:13), optionally ending in :log"
        )
    low = _number(name, spec, parts[0])
    high = _number(name, spec, parts[1])
    if low > high:
        raise ParameterError(
            f"{name} {spec!r}: inverted range ({low:g} > {high:g}); write LOW:HIGH:COUNT"
        )
    if low == high:
        raise ParameterError(
            f"{name} {spec!r}: empty range (both ends are {low:g}); give a single value instead"
        )
    if log and low <= 0:
        raise ParameterError(f"{name} {spec!r}: a log range needs LOW > 0")
    if len(parts) == 2:
        if not random:
            raise ParameterError(
                f"{name} {spec!r}: a grid needs the number of values, LOW:HIGH:COUNT "
                "(e.g. 2:8:13); a range without COUNT is for random search (--samples N)"
            )
        return ParameterSpec(name, spec, (), low, high, log)
    try:
        count = int(parts[2])
    except ValueError:
        raise ParameterError(
            f"{name} {spec!r}: COUNT {parts[2]!r} is not a whole number; write LOW:HIGH:COUNT"
        ) from None
    if count < 2:
        raise ParameterError(
            f"{name} {spec!r}: empty range ({count} values); give COUNT >= 2 or a single value"
        )
    grid = np.geomspace(low, high, count) if log else np.linspace(low, high, count)
    values = tuple(float(v) for v in grid)
    for value in values:  # rounding cannot leave the range, but the check is cheap
        validate_parameter(name, value)
    return ParameterSpec(name, spec, values, None, None, log)


@dataclass(frozen=True, slots=True)
class SweepSpec:
    """What a sweep tries: a grid, or ``samples`` random settings drawn with ``seed``.

    Attributes:
        parameters: one entry per named parameter, in :class:`MapParams` order.
        samples: number of random settings (``None``: a grid).
        seed: seed of the random search.

    """

    parameters: tuple[ParameterSpec, ...]
    samples: int | None = None
    seed: int = 0

    @property
    def random(self) -> bool:
        """True for a random search."""
        return self.samples is not None

    @property
    def swept(self) -> tuple[str, ...]:
        """Parameters that take more than one value."""
        return tuple(p.name for p in self.parameters if p.continuous or len(p.values) > 1)

    @property
    def fixed(self) -> dict[str, float]:
        """Parameters given a single value."""
        return {p.name: p.values[0] for p in self.parameters if len(p.values) == 1}

    def base_params(self) -> MapParams:
        """The defaults with the fixed parameters applied."""
        return MapParams().with_changes(**self.fixed)

    def paper_params(self) -> MapParams:
        """The paper's setting: its five values, other parameters as in this sweep's base."""
        defaults = MapParams()
        return self.base_params().with_changes(
            **{name: getattr(defaults, name) for name in PAPER_PARAMETERS}
        )

    def settings(self) -> list[MapParams]:
        """Every setting to try, in a fixed order, duplicates removed."""
        base = self.base_params()
        out: list[MapParams] = []
        seen: set[MapParams] = set()
        for changes in self._changes():
            params = base.with_changes(**changes)
            if params not in seen:
                seen.add(params)
                out.append(params)
        return out

    def _changes(self) -> Iterable[dict[str, float]]:
        names = [p.name for p in self.parameters]
        if self.samples is None:
            for combo in product(*(p.values for p in self.parameters)):
                yield dict(zip(names, combo, strict=True))
            return
        rng = np.random.default_rng(self.seed)
        for _ in range(self.samples):
            draw: dict[str, float] = {}
            for p in self.parameters:
                if p.continuous:
                    assert p.low is not None and p.high is not None
                    if p.log:
                        value = math.exp(rng.uniform(math.log(p.low), math.log(p.high)))
                        value = min(max(value, p.low), p.high)
                    else:
                        value = float(rng.uniform(p.low, p.high))
                else:
                    value = p.values[int(rng.integers(len(p.values)))]
                draw[p.name] = float(value)
            yield draw

    def to_dict(self) -> dict[str, Any]:
        """JSON form (what ``sweep.json`` records)."""
        return {
            "kind": "random" if self.random else "grid",
            "samples": self.samples,
            "seed": self.seed if self.random else None,
            "parameters": {p.name: p.to_dict() for p in self.parameters},
        }


def sweep_spec(
    values: Mapping[str, str | float | Sequence[float]],
    samples: int | None = None,
    seed: int = 0,
) -> SweepSpec:
    """Build a sweep from ``{parameter: values}`` (see the module docstring for the syntax).

    Raises:
        ParameterError: a bad parameter or range, a random search of fewer than one sample,
            nothing to sweep, or more than :data:`MAX_CELLS` settings.

    """
    random = samples is not None
    if random and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        raise ParameterError(f"samples {samples!r}: give a whole number >= 1 of random settings")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ParameterError(f"seed {seed!r}: give a whole number >= 0")
    parsed: dict[str, ParameterSpec] = {}
    for raw_name, text in values.items():
        spec = parse_parameter(raw_name, text, random)
        if spec.name in parsed:
            raise ParameterError(f"{spec.name} is given twice; give each parameter once")
        parsed[spec.name] = spec
    ordered = tuple(parsed[name] for name in PARAMETER_NAMES if name in parsed)
    sweep = SweepSpec(ordered, samples, seed)
    if not sweep.swept:
        raise ParameterError(
            "nothing to sweep: give at least one parameter several values, e.g. --delta 2:8:13"
        )
    if not random:
        cells = math.prod(len(p.values) for p in ordered)
        if cells > MAX_CELLS:
            raise ParameterError(
                f"the grid has {cells} settings, more than {MAX_CELLS}; use fewer values or "
                "random search (--samples N)"
            )
    elif samples is not None and samples > MAX_CELLS:
        raise ParameterError(f"samples {samples}: at most {MAX_CELLS} settings per sweep")
    return sweep


SPEC_FILE_KEYS = ("samples", "seed")
"""Keys of a spec file that are not map parameters (the random search's)."""


# --------------------------------------------------------------------------- one cell
def evaluate_cell(
    log: EventLog,
    params: MapParams,
    mode: MapMode | str = MapMode.COMPACT,
    radius: float = LAYOUT_RADIUS,
    growth_fraction: float = GROWTH_FRACTION,
) -> dict[str, float | int | None]:
    """Build one map from recorded events with ``params`` and measure it.

    Args:
        log: the front end's events with the ground truth per frame.
        params: the map parameters of this cell.
        mode: which map (default: the compact one).
        radius: radius of layout completeness and correctness (m).
        growth_fraction: the size change is measured over this last fraction of the data.

    Returns:
        :data:`FIGURE_COLUMNS` (accuracy figures ``None`` without ground truth) and
        :data:`TIMING_COLUMNS`.

    """
    started = time.perf_counter()
    cmap = CognitiveMap(mode, params)
    replay(cmap, log.columns(), 0, log.event_count)  # compiled when numba is available
    end = log.end_time
    cmap.finish(end)
    built = time.perf_counter()
    summary = optimisation_summary(cmap)
    figures: dict[str, float | int | None] = {
        "vertices": int(summary["vertices"]),
        "edges": int(summary["edges"]),
        "loop_edges": int(summary["loop_edges"]),
        "clusters": int(summary["clusters"]),
        "optimizations": int(summary["optimizations"]),
        "ate_m": None,
        "completeness": None,
        "correctness": None,
        "size_change": None,
        "size_change_raw": None,
        "exploration_vertices": None,
    }
    accuracy = log.map_accuracy(cmap.snapshot(), radius)
    if accuracy is not None and accuracy.ate is not None:
        figures["ate_m"] = accuracy.ate
        figures["completeness"] = accuracy.fidelity.completeness
        figures["correctness"] = accuracy.fidelity.correctness
        first = log.frame_time[0]
        start = end - growth_fraction * (end - first)
        growth = log.size_change(cmap, start, end, radius)
        if growth is not None:
            figures["size_change"] = growth.change_without_exploration
            figures["size_change_raw"] = growth.change
            figures["exploration_vertices"] = growth.exploration_vertices
    figures["optimize_wall_s"] = float(summary["optimize_wall_s"])
    figures["build_wall_s"] = built - started
    figures["evaluate_wall_s"] = time.perf_counter() - built
    return figures


# --------------------------------------------------------------------------- fronts
def pareto_mask(costs: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which rows of ``(N, K)`` costs (all minimised) are not dominated by another row.

    A row is dominated when another is no worse in every column and better in one. Equal rows
    do not dominate each other. Rows with a NaN are never on the front.
    """
    c = np.asarray(costs, dtype=np.float64)
    n = c.shape[0]
    valid = ~np.isnan(c).any(axis=1) if n else np.zeros(0, dtype=bool)
    on_front = valid.copy()
    v = c[valid]
    index = np.flatnonzero(valid)
    for k in range(v.shape[0]):
        no_worse = np.all(v <= v[k], axis=1)
        better = np.any(v < v[k], axis=1)
        if np.any(no_worse & better):
            on_front[index[k]] = False
    return on_front


@dataclass(frozen=True, slots=True)
class SettingFigures:
    """One setting's figures combined over the bags of a sweep.

    Attributes:
        params: the setting.
        vertices: mean vertices over the bags.
        edges: mean edges.
        ate_m: mean ATE (m).
        completeness: lowest completeness over the bags.
        correctness: lowest correctness.
        size_change: the size change farthest from zero over the bags (second half of the data,
            exploration set apart).
        bags: how many bags it was built on.

    """

    params: MapParams
    vertices: float
    edges: float
    ate_m: float
    completeness: float
    correctness: float
    size_change: float
    bags: int

    def to_dict(self, swept: Sequence[str] = ()) -> dict[str, Any]:
        """JSON form: the swept values, every parameter, and the figures."""
        every = self.params.to_dict()
        return {
            "swept": {name: every[name] for name in swept},
            "params": every,
            "vertices": self.vertices,
            "edges": self.edges,
            "ate_m": self.ate_m,
            "completeness": self.completeness,
            "correctness": self.correctness,
            "size_change": self.size_change,
            "bags": self.bags,
        }


def _num(value: Any) -> float:
    return float("nan") if value is None or value == "" else float(value)


def aggregate_settings(
    rows: Iterable[Mapping[str, Any]], bags: int
) -> dict[MapParams, SettingFigures]:
    """Combine per-bag cells into per-setting figures (only settings built on all ``bags``).

    Each row holds every parameter (:data:`PARAMETER_NAMES`) and the figures of one cell.
    """
    groups: dict[MapParams, list[Mapping[str, Any]]] = {}
    for row in rows:
        params = MapParams(**{name: float(row[name]) for name in PARAMETER_NAMES})
        groups.setdefault(params, []).append(row)
    out: dict[MapParams, SettingFigures] = {}
    for params, group in groups.items():
        if len(group) != bags:
            continue
        growth = [_num(r["size_change"]) for r in group]
        out[params] = SettingFigures(
            params=params,
            vertices=float(np.mean([_num(r["vertices"]) for r in group])),
            edges=float(np.mean([_num(r["edges"]) for r in group])),
            ate_m=float(np.mean([_num(r["ate_m"]) for r in group])),
            completeness=float(min(_num(r["completeness"]) for r in group)),
            correctness=float(min(_num(r["correctness"]) for r in group)),
            size_change=float(max(growth, key=lambda g: abs(g) if not math.isnan(g) else -1)),
            bags=len(group),
        )
    return out


def front_ate(settings: Sequence[SettingFigures]) -> list[SettingFigures]:
    """Settings on the (fewer vertices, lower ATE) front, by vertices."""
    costs = np.array([[s.vertices, s.ate_m] for s in settings]).reshape(-1, 2)
    mask = pareto_mask(costs)
    return sorted(
        (s for s, m in zip(settings, mask, strict=True) if m), key=lambda s: (s.vertices, s.ate_m)
    )


def front_completeness(settings: Sequence[SettingFigures]) -> list[SettingFigures]:
    """Settings on the (fewer vertices, higher completeness) front, by vertices."""
    costs = np.array([[s.vertices, -s.completeness] for s in settings]).reshape(-1, 2)
    mask = pareto_mask(costs)
    return sorted(
        (s for s, m in zip(settings, mask, strict=True) if m),
        key=lambda s: (s.vertices, -s.completeness),
    )


def smallest_complete(
    settings: Sequence[SettingFigures], min_completeness: float = MIN_COMPLETENESS
) -> SettingFigures | None:
    """The setting with the fewest vertices whose completeness is at least ``min_completeness``.

    Ties go to the lower ATE, then the higher completeness.
    """
    good = [s for s in settings if s.completeness >= min_completeness]
    if not good:
        return None
    return min(good, key=lambda s: (s.vertices, s.ate_m, -s.completeness))


def beats(candidate: SettingFigures, reference: SettingFigures) -> bool:
    """Fewer vertices than ``reference`` and no worse ATE, completeness or correctness."""
    return (
        candidate.vertices < reference.vertices
        and candidate.ate_m <= reference.ate_m
        and candidate.completeness >= reference.completeness
        and candidate.correctness >= reference.correctness
    )
