"""Front-end settings that travel with a dataset: a small JSON file beside the bag.

A bag ``maze.bag`` may come with ``maze.frontend.json``::

    {"frontend": {"vt_normalisation": 0.4, "vt_match_threshold": 0.025}, "note": "..."}

like a camera calibration file: settings that suit that dataset's camera. ``cogmap run`` and
``cogmap serve`` apply them on top of the iRat defaults of
:class:`~cogmap_core.frontend.FrontEndConfig`; a bag without the file (the real iRat bag) runs
with the iRat values unchanged. Generated bags get :data:`GENERATED_FRONTEND_PROFILE`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.fileio import loads_json
from cogmap_core.frontend import FrontEndConfig

PROFILE_SUFFIX = ".frontend.json"

GENERATED_FRONTEND_PROFILE: dict[str, float] = {
    # The renderer varies the light level by +-20 %: normalise each view's mean brightness
    # (OpenRatSLAM's vt_normalisation) so places stay recognisable under other light.
    "vt_normalisation": 0.4,
    # Views of places a few centimetres apart differ little in the rendered maze; a tighter
    # threshold than the iRat camera's 0.03 keeps loop closures precise (>= 0.99 measured).
    "vt_match_threshold": 0.025,
}


def profile_path(bag: str | os.PathLike[str]) -> Path:
    """The profile file that belongs to ``bag`` (``x.bag`` -> ``x.frontend.json``)."""
    bag = Path(bag)
    return bag.with_name(bag.stem + PROFILE_SUFFIX)


def read_frontend_profile(bag: str | os.PathLike[str]) -> dict[str, Any]:
    """The front-end overrides stored beside ``bag`` (empty when there is no profile).

    Raises:
        InputFileError: the profile exists but is not valid JSON or names invalid settings.

    """
    path = profile_path(bag)
    if not path.exists():
        return {}
    try:
        data = loads_json(path.read_text())
        overrides = dict(data["frontend"])
        FrontEndConfig().with_changes(**overrides)  # validate names and ranges
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputFileError(
            f"{path}: not a valid front-end profile ({exc}); fix it or delete it"
        ) from None
    except CogmapError as exc:
        raise InputFileError(f"{path}: {exc}; fix the profile or delete it") from None
    return overrides


def write_frontend_profile(
    bag: str | os.PathLike[str], overrides: dict[str, Any], note: str = ""
) -> Path:
    """Write the profile of ``bag`` atomically; return its path."""
    FrontEndConfig().with_changes(**overrides)  # validate before writing
    path = profile_path(bag)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"frontend": overrides, "note": note}, indent=2) + "\n")
    os.replace(tmp, path)
    return path


def frontend_config_for(bag: str | os.PathLike[str]) -> FrontEndConfig:
    """The front-end config for ``bag``: iRat defaults with its profile (if any) applied."""
    return FrontEndConfig().with_changes(**read_frontend_profile(bag))
