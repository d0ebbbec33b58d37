"""The paper's three maps: :class:`MapMode` and :data:`ALL_MODES`, their order in every report.

A module of its own (imported by :mod:`~cogmap_core.cognitive_map`, which makes the maps) so that
the table of map parameters (:mod:`~cogmap_core.parameter_table`), which says which maps each
parameter affects, can name the maps without importing the map itself.
"""

from __future__ import annotations

from enum import StrEnum


class MapMode(StrEnum):
    """Which of the paper's three maps to build."""

    STANDARD = "standard"
    SCENE_INTEGRATION = "scene_integration"
    COMPACT = "compact"


ALL_MODES: tuple[MapMode, ...] = tuple(MapMode)
"""The three maps in the order every session, report and page shows them: standard, scene
integration, compact."""

__all__ = ["ALL_MODES", "MapMode"]
