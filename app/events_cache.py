"""Recorded front-end events of a bag, kept in the user-wide cache (``$COGMAP_CACHE/events``).

The front end is the expensive, parameter-independent part of a run: what it makes of a bag
depends only on the bag, its topics and the front-end settings. :func:`bag_source` names those
events (their key), :func:`record_bag_events` runs the front end once over the bag, and
:func:`cached_bag_events` returns them from the cache, recording them on a miss. ``cogmap sweep``
(:mod:`app.sweep`) and the benchmarks share this cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

from cogmap_core import __version__
from cogmap_core.datasets import BagTopics, open_bag
from cogmap_core.datasets.cache import cache_dir
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.event_file import (
    FORMAT_VERSION,
    EventRecording,
    load_event_file,
    save_event_file,
)
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.slam import SlamSession

IMAGE_SCALE = 1  # as cogmap run: full size, for OpenRatSLAM's whole-pixel template blocks
EVENTS_DIR = "events"  # in the cache, and in a sweep folder


class EventsError(CogmapError):
    """A bag's front-end events cannot be recorded (unreadable bag, no frame, failed front end)."""


@dataclass(frozen=True, slots=True)
class BagSource:
    """A bag (or a recorded event file) and the identity of its events.

    Attributes:
        path: the bag as given (or an ``.npz`` event file).
        label: its name in results and messages (the file name).
        key: identity of its events: bag name, size, modification time, front-end settings,
            topics (or, for an event file, a hash of its content).
        frontend: the front-end settings (``None`` for an event file).
        topics: the bag's topics.

    """

    path: Path
    label: str
    key: str
    frontend: FrontEndConfig | None
    topics: BagTopics

    @property
    def is_event_file(self) -> bool:
        """True when the input is an already recorded event file."""
        return self.frontend is None

    @property
    def events_name(self) -> str:
        """File name of its event file (in the cache, or a sweep's ``DIR/events``).

        ``<bag name>-<key>.events.npz``.
        """
        if self.is_event_file:
            stem = self.path.name.removesuffix(".npz").removesuffix(".events")
        else:
            stem = self.path.stem
        return f"{stem}-{self.key}.events.npz"


def bag_source(path: Path, frontend: FrontEndConfig | None, topics: BagTopics) -> BagSource:
    """The identity of a bag's events (no bag is read; an event file is hashed).

    ``frontend`` is ``None`` for a recorded event file (``*.npz``).
    """
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path}: no such bag; give an existing .bag file or event file")
    if frontend is None:
        digest = hashlib.sha1(path.read_bytes()).hexdigest()[:16]
        return BagSource(path, path.name, digest, None, topics)
    stat = path.stat()
    identity = {
        "event_format": FORMAT_VERSION,
        "name": path.name,
        "size": stat.st_size,
        "mtime_ns": stat.st_mtime_ns,
        "frontend": frontend.to_dict(),
        "topics": asdict(topics),
        "image_scale": IMAGE_SCALE,
    }
    digest = hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]
    return BagSource(path, path.name, digest, frontend, topics)


def shared_events_dir() -> Path:
    """The user-wide copy of recorded events (``$COGMAP_CACHE/events``)."""
    return cache_dir() / EVENTS_DIR


FrameProgress = Callable[[int, int, float], None]


def cached_bag_events(
    path: Path,
    say: Callable[[str], None] | None = None,
    frontend_changes: Mapping[str, float] | None = None,
) -> EventRecording:
    """A bag's front-end events (its profile's settings) from the user-wide cache.

    ``frontend_changes`` alter the profile's settings (e.g.
    :data:`~cogmap_core.frontend.config.COGMAP_ARITHMETIC`); they are part of the cache key.

    The cache sweeps fill (``$COGMAP_CACHE/events``, keyed by the bag's name, size, time and
    the front-end settings); the front end runs once when the bag is not in it. A damaged
    cached copy is recorded again.

    Raises:
        EventsError: the front end cannot run over the bag (see :func:`record_bag_events`).

    """
    config = frontend_config_for(path).with_changes(**(frontend_changes or {}))
    source = bag_source(path, config, BagTopics())
    cached = shared_events_dir() / source.events_name
    if cached.exists():
        with contextlib.suppress(InputFileError):
            return load_event_file(cached)
    if say is not None:
        say(f"{source.label}: running the front end once (events cached in {cached})")
    recording = record_bag_events(source, None)
    cached.parent.mkdir(parents=True, exist_ok=True)
    save_event_file(cached, recording)
    return recording


def record_bag_events(source: BagSource, progress: FrameProgress | None) -> EventRecording:
    """Run the front end over the bag once; return its :class:`EventRecording`.

    ``progress(frames done, frames, data time)`` is called after each frame.

    Raises:
        EventsError: the bag cannot be read, has no decodable frame, or the front end fails
            (one line naming the bag).

    """
    assert source.frontend is not None
    started = time.perf_counter()
    session = SlamSession(frontend_config=source.frontend, modes=())
    try:
        with open_bag(source.path, source.topics, image_scale=IMAGE_SCALE) as reader:
            total = reader.info.frame_count
            for frame in reader.frames():
                session.process(frame)
                if progress is not None:
                    progress(frame.index + 1, total, frame.time)
    except CogmapError as exc:
        message = str(exc)
        if str(source.path) not in message:
            message = f"{source.path}: {message}"
        raise EventsError(message) from None
    except MemoryError:
        raise EventsError(f"{source.path}: out of memory while running the front end") from None
    except Exception as exc:  # a damaged bag can fail in many ways; name the bag
        raise EventsError(
            f"{source.path}: the front end failed ({type(exc).__name__}: {exc}); check the bag "
            "with cogmap dataset info --scan"
        ) from None
    if session.log.frames == 0:
        raise EventsError(f"{source.path}: no decodable camera frame; nothing to map")
    recording = session.log.recording(str(source.path), source.frontend.to_dict())
    recording.meta.update(
        {
            "frontend_wall_s": time.perf_counter() - started,
            "key": source.key,
            "topics": asdict(source.topics),
            "image_scale": IMAGE_SCALE,
            "recorded_by": f"cogmap {__version__} sweep",
        }
    )
    return recording
