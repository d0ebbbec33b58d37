"""Every GUI value a client sends is checked before viser applies it or shows it to anyone.

viser applies a client's ``GuiUpdateMessage`` to the shared state and broadcasts it to every
other client (and to clients joining later) *before* the app's callbacks run, and runs no
callback at all for a client that has not sent its first camera message. So a check in a
callback comes too late: an unknown map name raised KeyError for every viewer, and
``alpha = 1e308`` sent by a fresh client stayed on everyone's page while the maps kept the old
value.

:class:`GuiGate` sits in front of viser's handler instead. For each message it:

- refuses every update from a client viser has not registered yet (its callbacks would not
  run, so the page and the maps would disagree);
- keeps only the ``value`` property (a client may not change a slider's range, a dropdown's
  options, a label, or hide or disable a control for everyone);
- checks the value with the control's :data:`Check` (:func:`choice`, :func:`number`,
  :func:`boolean`, :func:`click`, :func:`text`); a control without one must keep the type of
  its current value;
- passes an accepted value (possibly clamped) on to viser, which applies, broadcasts and calls
  back as usual; a refused one is dropped, and the value in force is sent back to every client
  so that the sender's control shows it again.

Refusals and adjustments are reported to ``note`` when given, as a :class:`Refusal` (the
control's label, the reason, the value kept) or an :class:`Adjustment` (its ``message``); each
has a one-line ``message``, and a page may word a refusal its own way from its fields. A check
may word its adjustment itself by returning :class:`Adjusted`. The same gate guards a client's
own controls (``ClientHandle.gui``: the per-viewer view settings).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass
from typing import Any

import viser
from viser import _messages

#: A check returns the value to apply (possibly adjusted) or raises :class:`Refused`.
Check = Callable[[Any], Any]

_MAX_TEXT = 4096


class Refused(ValueError):
    """A GUI value that cannot be used; the message says why."""


@dataclass(frozen=True, slots=True)
class Adjusted:
    """A check's answer: apply ``value`` instead of what was sent, and say ``message``."""

    value: Any
    message: str


@dataclass(frozen=True, slots=True)
class Refusal:
    """A value the gate refused: the control's ``label``, the ``reason`` and the value ``kept``."""

    label: str
    reason: str
    kept: Any

    @property
    def message(self) -> str:
        """The refusal in one line: ``refused δ: 'abc' is not a number; kept '3.746'``."""
        return f"refused {self.label}: {self.reason}; kept {self.kept!r}"


@dataclass(frozen=True, slots=True)
class Adjustment:
    """A value the gate applied changed (clamped, normalised): ``message`` says how."""

    message: str


#: Where the gate reports what it refused or adjusted.
Note = Callable[[Refusal | Adjustment], None]


def choice(options: Sequence[str] | Callable[[], Sequence[str]]) -> Check:
    """A dropdown: the value must be one of ``options`` (or of what the callable returns)."""

    def check(value: Any) -> str:
        allowed = options() if callable(options) else options
        if not isinstance(value, str) or value not in allowed:
            raise Refused(f"{value!r} is not one of {', '.join(allowed)}")
        return value

    return check


def number(low: float, high: float | Callable[[], float]) -> Check:
    """A slider: a finite number, clamped into ``[low, high]`` (``high`` may be a callable)."""

    def check(value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise Refused(f"{value!r} is not a number")
        if not math.isfinite(value):
            raise Refused(f"{value!r} is not a finite number")
        top = float(high() if callable(high) else high)
        return min(max(float(value), low), top)

    return check


def boolean() -> Check:
    """A checkbox: ``True`` or ``False`` only."""

    def check(value: Any) -> bool:
        if not isinstance(value, bool):
            raise Refused(f"{value!r} is not true or false")
        return value

    return check


def click() -> Check:
    """A button: a click is ``True``; anything else is refused."""

    def check(value: Any) -> bool:
        if value is not True:
            raise Refused(f"{value!r} is not a click")
        return True

    return check


def text(max_length: int = _MAX_TEXT) -> Check:
    """A text field: a string of at most ``max_length`` characters, no control characters."""

    def check(value: Any) -> str:
        if not isinstance(value, str):
            raise Refused(f"{value!r} is not text")
        if len(value) > max_length:
            raise Refused(f"text of {len(value)} characters is longer than {max_length}")
        if any(ord(c) < 32 for c in value):
            raise Refused("text with control characters")
        return value

    return check


def _same_type(current: Any) -> Check:
    """The fallback for controls without a check: keep the type of the current value."""

    def check(value: Any) -> Any:
        if isinstance(current, bool):
            return boolean()(value)
        if isinstance(current, int | float):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise Refused(f"{value!r} is not a number")
            if not math.isfinite(value):
                raise Refused(f"{value!r} is not a finite number")
            return type(current)(value)
        if isinstance(current, str):
            return text()(value)
        if type(value) is not type(current):
            raise Refused(f"{value!r} is not a {type(current).__name__}")
        return value

    return check


@dataclass
class _Guard:
    handle: Any
    check: Check
    label: str
    note: Note | None


Handler = Callable[[Any, _messages.GuiUpdateMessage], Coroutine[Any, Any, None] | None]


class GuiGate:
    """Checks GUI updates from clients before viser's own handler sees them.

    Args:
        server: the viser server.
        note: where to report refusals and adjustments (default: nowhere).
        gui: the GUI to protect (default: the server's global one; or a client's own).

    """

    def __init__(
        self,
        server: viser.ViserServer,
        note: Note | None = None,
        gui: viser.GuiApi | None = None,
    ) -> None:
        """Put the gate in front of viser's handler of GUI updates."""
        self.server = server
        self.note = note
        self._guards: dict[str, _Guard] = {}
        self.refused = 0
        gui = gui if gui is not None else server.gui
        # viser has no public hook before it applies an update: its handler is swapped for ours.
        self._websock = gui._websock_interface
        self._original: Handler = gui._handle_gui_updates
        self._inputs: dict[str, Any] = gui._gui_input_handle_from_uuid
        self._websock.unregister_handler(_messages.GuiUpdateMessage, self._original)
        self._websock.register_handler(_messages.GuiUpdateMessage, self._handle)

    def guard(self, handle: Any, check: Check, label: str = "", note: Note | None = None) -> None:
        """Check the values clients send to ``handle`` with ``check``."""
        name = label or str(getattr(handle, "label", "")) or "control"
        self._guards[handle._impl.uuid] = _Guard(handle, check, name, note)

    # ------------------------------------------------------------------ the handler
    async def _handle(self, client_id: Any, message: _messages.GuiUpdateMessage) -> None:
        guard = self._guards.get(message.uuid)
        handle = guard.handle if guard is not None else self._inputs.get(message.uuid)
        if handle is None or handle._impl.removed:
            return  # viser would ignore it too
        label = guard.label if guard is not None else str(getattr(handle, "label", "control"))
        note = (guard.note if guard is not None else None) or self.note
        updates = message.updates if isinstance(message.updates, dict) else {}
        if client_id not in self.server.get_clients():
            return self._refuse(handle, label, "from a client that has not connected yet", note)
        others = sorted(str(k) for k in updates if k != "value")
        if others:
            self._refuse(handle, label, f"property {', '.join(others)} is not the client's", note)
        if "value" not in updates:
            return None
        sent = updates["value"]
        check = guard.check if guard is not None else _same_type(handle._impl.value)
        try:
            value = check(sent)
        except Refused as exc:
            return self._refuse(handle, label, str(exc), note)
        wording = None
        if isinstance(value, Adjusted):
            value, wording = value.value, value.message
        result = self._original(
            client_id, _messages.GuiUpdateMessage(message.uuid, {"value": value})
        )
        if result is not None:
            await result
        if value != sent or type(value) is not type(sent):
            if not handle._impl.is_button:
                self._resend(handle)
            if note is not None and value != sent:
                message = wording or f"{label} = {sent!r} is out of range: set to {value!r}"
                note(Adjustment(message))
        return None

    def _refuse(self, handle: Any, label: str, reason: str, note: Note | None) -> None:
        self.refused += 1
        if not handle._impl.is_button:
            self._resend(handle)
        if note is not None:
            note(Refusal(label, reason, handle._impl.value))

    def _resend(self, handle: Any) -> None:
        """Send the value in force to every client (the sender's control shows it again)."""
        self._websock.queue_message(
            _messages.GuiUpdateMessage(handle._impl.uuid, {"value": handle._impl.value})
        )
