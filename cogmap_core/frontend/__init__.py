"""The RatSLAM-style SLAM front end (OpenRatSLAM, Ball et al. 2013).

- :mod:`cogmap_core.frontend.config` -- :class:`FrontEndConfig`, the iRat parameters.
- :mod:`cogmap_core.frontend.local_view` -- visual templates and the fast exact matcher.
- :mod:`cogmap_core.frontend.pose_cells` -- the pose cell attractor network and its actions.
- :mod:`cogmap_core.frontend.frontend` -- :class:`FrontEnd`, frames in, map events out.
"""

from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.frontend import FrontEnd
from cogmap_core.frontend.local_view import LocalViewCells, MatchResult, ViewMatch
from cogmap_core.frontend.pose_cells import PoseCellExperiences, PoseCellNetwork

__all__ = [
    "FrontEnd",
    "FrontEndConfig",
    "LocalViewCells",
    "MatchResult",
    "PoseCellExperiences",
    "PoseCellNetwork",
    "ViewMatch",
]
