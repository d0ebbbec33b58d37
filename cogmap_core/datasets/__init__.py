"""Datasets: iRat-layout bag reading, synthetic rat-maze bags and the default dataset cache.

- :func:`open_bag` / :class:`BagReader` -- stream :class:`~cogmap_core.frames.Frame` objects from
  a ROS1 (or ROS2) bag with the iRat 2011 Australia topics.
- :func:`generate_maze_bag` / :class:`MazeConfig` -- render a synthetic bag of a robot driving
  laps of an ASCII maze (:func:`load_layout`, :func:`builtin_layouts`).
- :func:`default_dataset_path` -- the built-in default dataset, generated once into the cache.
"""

from cogmap_core.datasets.errors import (
    BagError,
    BagMessageTypeError,
    BagTopicError,
    DatasetCacheError,
    LayoutError,
)
from cogmap_core.datasets.generator import GenerationResult, MazeConfig, generate_maze_bag
from cogmap_core.datasets.layout import DEFAULT_LAYOUT, Layout, builtin_layouts, load_layout
from cogmap_core.datasets.motion import OdometryModel
from cogmap_core.datasets.read_counters import ReadCounters
from cogmap_core.datasets.rosbag_reader import BagInfo, BagReader, open_bag
from cogmap_core.datasets.topics import BagTopics

__all__ = [
    "DEFAULT_LAYOUT",
    "BagError",
    "BagInfo",
    "BagMessageTypeError",
    "BagReader",
    "BagTopicError",
    "BagTopics",
    "DatasetCacheError",
    "GenerationResult",
    "Layout",
    "LayoutError",
    "MazeConfig",
    "OdometryModel",
    "ReadCounters",
    "builtin_layouts",
    "generate_maze_bag",
    "load_layout",
    "open_bag",
]
