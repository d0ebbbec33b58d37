"""What an input is and how it is read: one description for ``cogmap run``, the app and the replay.

:class:`InputOptions` says how to read an input -- its kind, the front end of a camera input, a
bag's topics and JPEG scale, how to read a log, a camera's motion and frame rate -- and is what
:class:`~app.pipeline.RunOptions` (``cogmap run``), :class:`~app.server.app.CogmapApp`
(``cogmap serve``) and :class:`~app.server.replay.Replay` are given. :class:`ReplayInput` adds
*what* is read: a path, or a function generating the built-in dataset.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from cogmap_core.datasets import BagTopics
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.sources.detect import CameraOptions, LogOptions

#: A generator's progress: (frames done, frames in all).
GenerationProgress = Callable[[int, int], None]
#: An input: its path, or a function generating it (the built-in dataset) given a progress callback.
BagSource = Path | Callable[[GenerationProgress], Path]
#: A front-end configuration, or a function choosing it for the input once it is known (None: the
#: iRat defaults with the input's ``<name>.frontend.json`` profile, as ``cogmap run``).
FrontEndSource = FrontEndConfig | Callable[[Path], FrontEndConfig] | None


def resolve_frontend(source: FrontEndSource, path: Path) -> FrontEndConfig:
    """The front-end settings for a camera input at ``path``: given, computed, or its profile."""
    if isinstance(source, FrontEndConfig):
        return source
    return frontend_config_for(path) if source is None else source(path)


@dataclass(frozen=True, slots=True)
class InputOptions:
    """How an input is read.

    Attributes:
        format: the input's kind (``bag``, ``tuc``, ``csv``, ``video``, ``images``; None:
            detected from the content).
        frontend: a camera input's front end (:data:`FrontEndSource`; unused for logs).
        topics: a bag's topic names (None: the iRat 2011 Australia bag's).
        image_scale: JPEG decode reduction (1, 2, 4, 8).
        log: how to read a log (ignored for camera inputs).
        camera: a camera input's motion (a bag's odometry topic or visual odometry) and the
            frame rate of a video or image folder without a times file.

    """

    format: str | None = None
    frontend: FrontEndSource = None
    topics: BagTopics | None = None
    image_scale: int = 1
    log: LogOptions = field(default_factory=LogOptions)
    camera: CameraOptions = field(default_factory=CameraOptions)

    def frontend_for(self, path: Path) -> FrontEndConfig:
        """The front-end settings of the camera input at ``path`` (:func:`resolve_frontend`)."""
        return resolve_frontend(self.frontend, path)

    def camera_for(self, path: Path) -> CameraOptions:
        """The camera options with the front-end settings of ``path`` (its own profile).

        A camera input's visual odometry and colour averaging take the settings its front end
        runs with, not those of the input served first.
        """
        return replace(self.camera, frontend=self.frontend_for(path))


@dataclass(frozen=True, slots=True)
class ReplayInput:
    """What is replayed and how it is read.

    Attributes:
        bag: the bag or log, or a function that produces it given a progress callback (the
            built-in dataset, generated on first use).
        options: how to read it.

    """

    bag: BagSource
    options: InputOptions = field(default_factory=InputOptions)
