"""cogmap_core: the compact cognitive map library (no web, no I/O side effects in the algorithms).

The pieces, from the paper (Zeng & Si, "A Brain-Inspired Compact Cognitive Mapping System"):

- :mod:`cogmap_core.events` -- the typed event contract between the SLAM front end and the map.
- :mod:`cogmap_core.cognitive_map` -- the cognitive (experience) map in its ``standard``,
  ``scene_integration`` and ``compact`` modes: neighborhood fields, loop-closure clustering,
  batch optimisation, scene integration and short-edge removal.
- :mod:`cogmap_core.optimizer` -- robust non-linear least squares on pyceres (Ceres Solver).
- :mod:`cogmap_core.g2o` -- ``VERTEX_SE2`` / ``EDGE_SE2`` interchange.
"""

from cogmap_core.errors import CogmapError

__all__ = ["CogmapError", "__version__"]
__version__ = "0.1.0"
