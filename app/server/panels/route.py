"""The route panel (each viewer's): click two places, see the routes on the maps and their lengths.

What the routes are and how they are drawn and described is :mod:`app.server.routes`'; the
view asks for them (:meth:`~app.server.view.ClientView.start_route`) and the page's route worker
computes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import viser

from app.server.routes import message_html
from app.server.validation import GuiGate, click

#: What the route panel says before a route is asked for.
ROUTE_HELP = (
    "Click route, then the start and the goal in the scene: the shortest route on the shown "
    "map is drawn, with the standard map's and the true shortest path, their lengths compared "
    "here."
)


@dataclass(frozen=True, slots=True)
class RoutePanel:
    """The handles of a viewer's "Route — yours" panel."""

    route_button: viser.GuiButtonHandle
    clear_route_button: viser.GuiButtonHandle
    route_html: viser.GuiHtmlHandle


def build_route(gui: viser.GuiApi, folder: viser.GuiFolderHandle) -> RoutePanel:
    """Add a viewer's route panel into ``folder``."""
    with folder:
        route_button = gui.add_button(
            "route", icon=viser.Icon.ROUTE, hint="then click the start and the goal"
        )
        clear_route_button = gui.add_button("clear route", icon=viser.Icon.ROUTE_OFF)
        route_html = gui.add_html(message_html(ROUTE_HELP))
    return RoutePanel(route_button, clear_route_button, route_html)


def guard_route(gate: GuiGate, panel: RoutePanel) -> None:
    """Check what a client can send to its route panel (clicks)."""
    for button in (panel.route_button, panel.clear_route_button):
        gate.guard(button, click())
