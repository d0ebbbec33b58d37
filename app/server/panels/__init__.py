"""The web app's panels: one builder per panel of the page, returning its handles.

Shared by every browser (built once by :class:`~app.server.app.CogmapApp`):

- :mod:`~app.server.panels.playback` -- play, speed, step, restart, seek; the status line;
- :mod:`~app.server.panels.parameters` -- the map parameters' sliders and boxes, reset;
- :mod:`~app.server.panels.live_figures` -- the camera, the network behind the map, the live
  counters of the three maps, the size chart, the cluster log;
- :mod:`~app.server.panels.export` -- g2o, summary.json, sizes.csv, the HTML replay;
- :mod:`~app.server.panels.open` -- opening another bag or log of the data folders.

Each viewer's own (built for every tab by :class:`~app.server.view.ClientView`, in the page's
folders of :class:`ViewFolders`):

- :mod:`~app.server.panels.layers` -- layers and view: which map, side by side, colours, layers,
  the camera buttons, the legend;
- :mod:`~app.server.panels.inspect` -- what a click on the map selected;
- :mod:`~app.server.panels.compare` -- pin the shown map and compare it with the live one;
- :mod:`~app.server.panels.route` -- the route between two clicked places.

A builder adds its controls where it is called (the page's order is the order of the calls) and
returns them in a small dataclass; a ``guard_*`` function gives each control its check
(:mod:`app.server.validation`). What the controls *do* is wired by the page or the view.
"""

from __future__ import annotations

import html
import operator
from dataclasses import dataclass
from typing import Any

import viser


@dataclass(frozen=True, slots=True)
class ViewFolders:
    """The page's folders each viewer's panels go into (one of each for everyone)."""

    inspect: viser.GuiFolderHandle
    route: viser.GuiFolderHandle
    view: viser.GuiFolderHandle
    compare: viser.GuiFolderHandle
    clusters: viser.GuiFolderHandle


def note_html(element_id: str, text: str, error: bool = False) -> str:
    """A panel's one-line message: ``text`` (escaped) in a note, red for an ``error``."""
    cls = "cogmap-note cogmap-error" if error else "cogmap-note"
    return f'<div class="{cls}" id="{element_id}">{html.escape(text)}</div>'


def rgb(color: tuple[int, int, int]) -> str:
    """CSS colour."""
    return f"rgb({color[0]},{color[1]},{color[2]})"


def swatch(color: tuple[int, int, int]) -> str:
    """A small coloured square (legends)."""
    return f'<span class="cogmap-swatch" style="background:{rgb(color)}"></span>'


def set_content(handle: Any, content: str) -> None:
    """Set an HTML or markdown handle's content, sending nothing when it is already shown."""
    if handle.content != content:
        handle.content = content


class PanelHandle:
    """An attribute of the page (or a view) that is one of its panels' handles.

    ``play_button = PanelHandle("playback.panel")`` makes ``app.play_button`` read
    ``app.playback.panel.play_button``: scripts and tests keep the names they use while the
    handle lives in its panel. ``name`` reads another attribute of the panel than the one
    defined.
    """

    def __init__(self, panel: str, name: str = "") -> None:
        """Forward to the panel at (dotted) attribute path ``panel``."""
        self._panel = operator.attrgetter(panel)
        self.name = name

    def __set_name__(self, owner: type, name: str) -> None:
        """Learn the handle's name (the attribute's, unless given)."""
        self.name = self.name or name

    def __get__(self, instance: object, owner: type | None = None) -> Any:
        """The handle of ``instance``'s panel (the descriptor itself on the class)."""
        if instance is None:
            return self
        return getattr(self._panel(instance), self.name)
