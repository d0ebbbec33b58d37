"""The map-parameter controls: slider specs, and what a typed value means.

Each tuning parameter has a slider (drag) and a box to type a value into. viser's own number box
beside a slider parses as you type and drops what it does not understand (``1e9`` became 19,
``3,5`` became 35, ``abc`` blanked the box), so the page hides it and uses a text box whose
content is read here, on the server, exactly:

- a plain decimal number, optionally with an exponent (``8``, ``-0.5``, ``2.5e1``), is that
  number -- clamped into the slider's range with a message naming the range;
- anything else -- empty, ``3,5``, ``abc``, ``NaN``, ``inf`` -- is refused with a message and the
  box shows the value in force again.

The page's script (``static/cogmap.js``) sends a box's text when Enter is pressed or the box loses
focus, not on every keystroke.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from app.server.validation import Adjusted, Check, Refused
from cogmap_core.config import parameter_range
from cogmap_core.errors import ParameterError
from cogmap_core.parameter_table import SLIDER_PARAMETERS, MapParameter

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")


@dataclass(frozen=True, slots=True)
class SliderSpec:
    """A map-parameter slider: label, parameter name, range and step."""

    label: str
    name: str
    low: float
    high: float
    step: float
    hint: str


def slider_spec(parameter: MapParameter) -> SliderSpec:
    """The slider of a map parameter, as its row of the parameter table describes it."""
    slider, label = parameter.slider, parameter.label
    if slider is None or label is None:
        raise ParameterError(f"map parameter {parameter.name} has no slider with a label")
    return SliderSpec(label, parameter.name, slider.low, slider.high, slider.step, slider.hint)


#: The tuning sliders, in the page's order (ranges inside the valid parameter ranges of
#: :class:`MapParams`), from the parameter table (:mod:`cogmap_core.parameter_table`).
SLIDERS: tuple[SliderSpec, ...] = tuple(
    slider_spec(p) for p in SLIDER_PARAMETERS if p.slider is not None and not p.slider.advanced
)
#: The sliders of the "Advanced" folder.
ADVANCED_SLIDERS: tuple[SliderSpec, ...] = tuple(
    slider_spec(p) for p in SLIDER_PARAMETERS if p.slider is not None and p.slider.advanced
)
ALL_SLIDERS = SLIDERS + ADVANCED_SLIDERS
SPECS = {spec.name: spec for spec in ALL_SLIDERS}


def check_spec(spec: SliderSpec) -> None:
    """Raise :class:`ParameterError` unless the slider's range is inside the parameter's."""
    low, inclusive, high = parameter_range(spec.name)
    ok_low = spec.low >= low if inclusive else spec.low > low
    if not (ok_low and spec.high <= high):
        raise ParameterError(f"slider {spec.name} range [{spec.low}, {spec.high}] is invalid")


def clamp_to_slider(spec: SliderSpec, value: object) -> float | None:
    """``value`` clamped into the slider's range; None when it is not a finite number."""
    if isinstance(value, bool):
        return None
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    if not math.isfinite(v):
        return None
    return min(max(v, spec.low), spec.high)


def format_value(value: float) -> str:
    """A parameter value as the box shows it (shortest exact form up to 12 digits)."""
    text = f"{value:.12g}"
    return "0" if text == "-0" else text


@dataclass(frozen=True, slots=True)
class TypedValue:
    """What a typed text means: the value to apply and, when it was clamped, why."""

    value: float
    message: str


def parse_typed(spec: SliderSpec, text: str) -> TypedValue:
    """The value ``text`` typed into the box of ``spec`` stands for (module doc).

    Raises:
        Refused: the text is not a plain number (the message names the problem).

    """
    raw = text.strip()
    shown = raw if len(raw) <= 24 else raw[:21] + "..."
    if not raw:
        raise Refused("the box is empty: type a number")
    if not _NUMBER.fullmatch(raw):
        lowered = raw.lower().lstrip("+-")
        if lowered in ("nan", "inf", "infinity"):
            raise Refused(f"{shown!r} is not a finite number")
        if re.fullmatch(r"[+-]?\d+,\d+", raw):
            raise Refused(f"{shown!r} is not a number: write the decimal point as '.'")
        raise Refused(f"{shown!r} is not a number")
    value = float(raw)  # may overflow to +-inf: then it is clamped like any large number
    clamped = min(max(value, spec.low), spec.high)
    if clamped != value:
        return TypedValue(
            clamped,
            f"{spec.label} = {shown} is outside [{format_value(spec.low)}, "
            f"{format_value(spec.high)}]: using {format_value(clamped)}",
        )
    return TypedValue(value, f"{spec.label} = {format_value(value)}")


def typed_check(spec: SliderSpec) -> Check:
    """A :class:`~app.server.validation.GuiGate` check of a parameter's box (module doc).

    The box's value becomes the normal form of the number (clamped, with the message).
    """

    def check(value: object) -> object:
        if not isinstance(value, str):
            raise Refused(f"{value!r} is not text")
        typed = parse_typed(spec, value)
        normal = format_value(typed.value)
        if normal != value:
            return Adjusted(normal, typed.message)
        return normal

    return check
