"""cogmap_core: the compact cognitive map library (no web, no I/O side effects in the algorithms).

The pieces, from the paper (Zeng & Si, "A Brain-Inspired Compact Cognitive Mapping System"):

- :mod:`cogmap_core.events` -- the typed event contract between the SLAM front end and the map.
- :mod:`cogmap_core.cognitive_map` -- the cognitive (experience) map in its ``standard``,
  ``scene_integration`` and ``compact`` modes: neighborhood fields, loop-closure clustering,
  batch optimisation, scene integration and short-edge removal.
- :mod:`cogmap_core.optimizer` -- robust non-linear least squares on pyceres (Ceres Solver).
- :mod:`cogmap_core.g2o` -- ``VERTEX_SE2`` / ``EDGE_SE2`` interchange.

The names a program using the library needs are importable from here (``from cogmap_core import
SlamSession``); ``docs/api.md`` shows them at work. They are loaded on first use, so importing
one module of the package does not load the front end, the optimiser and numba with it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: The public names, each with the module that defines it.
_PUBLIC: dict[str, str] = {
    # a session and its settings
    "SlamSession": "cogmap_core.slam",
    "MapParams": "cogmap_core.config",
    "FrontEndConfig": "cogmap_core.frontend.config",
    # the maps
    "MapMode": "cogmap_core.cognitive_map",
    "CognitiveMap": "cogmap_core.cognitive_map",
    # what goes in: any input file, or frames and steps of your own
    "open_source": "cogmap_core.sources.detect",
    "Frame": "cogmap_core.frames",
    "EventStep": "cogmap_core.frames",
    "Odometry": "cogmap_core.events",
    "CreateVertex": "cogmap_core.events",
    "LinkToVertex": "cogmap_core.events",
    "SetCurrentVertex": "cogmap_core.events",
    # what the front end made, kept and saved
    "EventLog": "cogmap_core.event_log",
    "load_event_file": "cogmap_core.event_file",
    "save_event_file": "cogmap_core.event_file",
    # judged and exported
    "EvaluationSettings": "cogmap_core.evaluation",
    "read_g2o": "cogmap_core.g2o",
    "write_g2o": "cogmap_core.g2o",
    "CogmapError": "cogmap_core.errors",
}

__all__ = [  # (the names of _PUBLIC, written out for the tools that read them)
    "CogmapError",
    "CognitiveMap",
    "CreateVertex",
    "EvaluationSettings",
    "EventLog",
    "EventStep",
    "Frame",
    "FrontEndConfig",
    "LinkToVertex",
    "MapMode",
    "MapParams",
    "Odometry",
    "SetCurrentVertex",
    "SlamSession",
    "__version__",
    "load_event_file",
    "open_source",
    "read_g2o",
    "save_event_file",
    "write_g2o",
]

if TYPE_CHECKING:
    from cogmap_core.cognitive_map import CognitiveMap, MapMode
    from cogmap_core.config import MapParams
    from cogmap_core.errors import CogmapError
    from cogmap_core.evaluation import EvaluationSettings
    from cogmap_core.event_file import load_event_file, save_event_file
    from cogmap_core.event_log import EventLog
    from cogmap_core.events import CreateVertex, LinkToVertex, Odometry, SetCurrentVertex
    from cogmap_core.frames import EventStep, Frame
    from cogmap_core.frontend.config import FrontEndConfig
    from cogmap_core.g2o import read_g2o, write_g2o
    from cogmap_core.slam import SlamSession
    from cogmap_core.sources.detect import open_source


def __getattr__(name: str) -> Any:
    """A public name, imported from its module the first time it is asked for."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'cogmap_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next look-up is a plain attribute
    return value


def __dir__() -> list[str]:
    """The module's names, the public ones not yet loaded included."""
    return sorted({*globals(), *_PUBLIC})
