"""``cogmap route MAP --from X,Y --to X,Y``: the shortest route between two places on a saved map.

MAP is a report folder of ``cogmap run`` (its ``<map>.g2o``, the compact map unless ``--map``
says) or any 2D g2o file. Places are in the map's frame (the g2o file's: the robot starts at the
origin facing +x); each is snapped to its nearest vertex (:mod:`cogmap_core.routes`). Vertices
within the map's ``integration_radius`` are joined and the way is straightened within its
``link_sigma_position``: a report folder's map parameters (its ``config.json``), the defaults
for a g2o file.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.fileio import read_json
from cogmap_core.g2o import read_g2o
from cogmap_core.routes import Route, RouteMap


def place(text: str) -> tuple[float, float]:
    """An ``X,Y`` place (m) from the command line."""
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"place {text!r} is not X,Y (two numbers in metres, e.g. 1.5,-0.3)"
        ) from None
    if not all(abs(v) < float("inf") for v in (x, y)):  # NaN and infinities
        raise argparse.ArgumentTypeError(f"place {text!r} is not two finite numbers")
    return x, y


def map_file(path: Path, mode: str) -> Path:
    """The g2o file of ``path``: the file itself, or a report folder's ``<mode>.g2o``."""
    if not path.is_dir():
        return path  # read_g2o reports a missing or malformed file
    candidate = path / f"{mode}.g2o"
    if not candidate.is_file():
        raise InputFileError(
            f"{path}: no {candidate.name} in this folder; give a report folder of cogmap run "
            "or a .g2o file"
        )
    return candidate


def map_params(path: Path) -> MapParams:
    """The map parameters of a report folder (its ``config.json``); the defaults otherwise."""
    config = path / "config.json"
    if not (path.is_dir() and config.is_file()):
        return MapParams()
    data = read_json(config, "report configuration", InputFileError)
    values = data.get("map") if isinstance(data, dict) else None
    if not isinstance(values, dict):
        raise InputFileError(f"{config}: no 'map' parameters in this report configuration")
    try:
        return MapParams.from_dict(values)
    except (CogmapError, TypeError) as exc:
        raise InputFileError(f"{config}: {exc}") from None


def route_json(
    source: Path, route: Route, start: tuple[float, float], goal: tuple[float, float]
) -> str:
    """The JSON line ``cogmap route`` prints."""
    return json.dumps(
        {
            "map": str(source),
            "from": list(start),
            "to": list(goal),
            "length_m": round(route.length, 6),
            "edges": route.num_edges,
            "start_gap_m": round(route.start_gap, 6),
            "goal_gap_m": round(route.goal_gap, 6),
            "vertices": route.vertex_ids.tolist(),
            "points": [[round(x, 6), round(y, 6)] for x, y in route.points.tolist()],
        }
    )


def _run(args: argparse.Namespace) -> int:
    source = map_file(Path(args.map), args.which)
    params = map_params(Path(args.map))
    routes = RouteMap.of(read_g2o(source), args.weight, params)
    route = routes.route(args.start, args.goal)
    print(route_json(source, route, args.start, args.goal))
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap route``."""
    parser = subparsers.add_parser(
        "route",
        help="the shortest route between two places on a saved map; print one JSON line",
        description="Find the shortest route between two places on a map saved by cogmap run "
        "(a report folder: its <map>.g2o) or any 2D g2o file: Dijkstra over the map's edges "
        "weighted by their length in the saved (optimised) poses and over joins of vertices "
        "within the map's integration_radius, each place snapped to its nearest vertex, the way "
        "straightened within the map's link_sigma_position of the vertices (a report folder's "
        "parameters, from its config.json; the defaults for a g2o file). Prints "
        '{"map", "from", "to", "length_m", "edges", "start_gap_m", "goal_gap_m", "vertices", '
        '"points"}. Places are X,Y in metres in the map\'s frame (the robot starts at the origin '
        "facing +x); write a negative first number as --from=-1.5,2.",
    )
    parser.add_argument("map", metavar="MAP", help="report folder of cogmap run, or a .g2o file")
    parser.add_argument(
        "--from", dest="start", type=place, required=True, metavar="X,Y", help="start place (m)"
    )
    parser.add_argument(
        "--to", dest="goal", type=place, required=True, metavar="X,Y", help="goal place (m)"
    )
    parser.add_argument(
        "--map",
        dest="which",
        choices=[m.value for m in MapMode],
        default=MapMode.COMPACT.value,
        help="which map of a report folder (default compact)",
    )
    parser.add_argument(
        "--weight",
        choices=("poses", "measured"),
        default="poses",
        help="edge lengths from the saved poses (default) or from the edges' measurements",
    )
    parser.set_defaults(func=_run)
