"""Which kind of input a path is, and one way to open any of them.

Kinds: ``bag`` (a ROS bag with camera, odometry and ground truth: the RatSLAM front end runs on
it), ``video`` (a video file) and ``images`` (a folder of images): camera only, their motion
from RatSLAM's visual odometry (:mod:`cogmap_core.datasets.camera_common`), ``tuc`` (a TUC SLAM
dataset input file) and ``csv`` (plain CSV odometry with loop and ground-truth files beside it).
:func:`detect_format` looks at the content: a ROS1 bag starts with ``#ROSBAG``, a ROS2 bag is a
folder with its ``metadata.yaml`` or an ``.mcap``/``.db3`` file, a video is named by its suffix
(:data:`~cogmap_core.datasets.video_reader.VIDEO_SUFFIXES`), another folder holding images is an
image folder, a TUC file's lines start with ``odom2``/``loop``, a CSV file's with three
comma-separated fields (the first line that is
not blank or a ``#`` comment decides; a UTF-8 byte-order mark is skipped).

Each kind brings its defaults (:class:`InputKind`): the map parameters and the tolerances the
report judges with. Bags keep the paper's parameters; logs get
:data:`~cogmap_core.sources.odometry_log.LOG_MAP_PARAMS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cogmap_core.config import MapParams
from cogmap_core.datasets.camera_common import CAMERA_ONLY_MAP_CHANGES, CameraReader
from cogmap_core.datasets.image_folder import image_files, open_image_folder
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.datasets.rosbag_reader import BagReader, open_bag
from cogmap_core.datasets.topics import BagTopics
from cogmap_core.datasets.video_reader import VIDEO_SUFFIXES, open_video
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.evaluation import EvaluationSettings
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.sources.log_reader import LogReader
from cogmap_core.sources.log_text import BOM
from cogmap_core.sources.odometry_csv import looks_like_csv, read_odometry_csv
from cogmap_core.sources.odometry_log import LOG_EVALUATION, LOG_MAP_PARAMS, LogSourceConfig
from cogmap_core.sources.tuc import looks_like_tuc, read_tuc

FORMATS = ("bag", "video", "images", "tuc", "csv")
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
SNIFF_LIMIT = 1 << 20
"""Bytes :func:`detect_format` reads to find the first line that is not blank or a comment."""


@dataclass(frozen=True)
class InputKind:
    """A kind of input and its defaults.

    Attributes:
        name: ``bag``, ``video``, ``images``, ``tuc`` or ``csv``.
        has_camera: frames carry camera images (the RatSLAM front end runs on them).
        map_params: default map parameters.
        evaluation: how its maps and loop closures are judged against ground truth.

    """

    name: str
    has_camera: bool
    map_params: MapParams
    evaluation: EvaluationSettings


CAMERA_ONLY_MAP_PARAMS = MapParams().with_changes(**CAMERA_ONLY_MAP_CHANGES)
"""Default map parameters for videos and image folders (visual odometry)."""

KINDS: dict[str, InputKind] = {
    "bag": InputKind("bag", True, MapParams(), EvaluationSettings()),
    "video": InputKind("video", True, CAMERA_ONLY_MAP_PARAMS, EvaluationSettings()),
    "images": InputKind("images", True, CAMERA_ONLY_MAP_PARAMS, EvaluationSettings()),
    "tuc": InputKind("tuc", False, LOG_MAP_PARAMS, LOG_EVALUATION),
    "csv": InputKind("csv", False, LOG_MAP_PARAMS, LOG_EVALUATION),
}


@dataclass(frozen=True)
class LogOptions:
    """How to read a log (ignored for bags).

    Attributes:
        config: how the log becomes events.
        loops: the loop file of a CSV log (default: its companion).
        ground_truth: the ground-truth file (default: the log's companion).
        use_ground_truth: False reads no ground truth.

    """

    config: LogSourceConfig = field(default_factory=LogSourceConfig)
    loops: Path | None = None
    ground_truth: Path | None = None
    use_ground_truth: bool = True


def check_sessions_allowed(fmt: str, path: Path | str | None, flag: str, advice: str) -> None:
    """Refuse a session option (``--resume``, ``--save-session``) for an input that is no bag.

    Sessions hold a camera front end's state; a log of odometry and place recognition has none.

    Raises:
        ParameterError: ``{flag}: sessions are for bags; {path} is a log ... ({fmt}): {advice}``.

    """
    if fmt in ("video", "images"):
        raise ParameterError(
            f"{flag}: sessions are for bags; {path} is a camera-only input ({fmt}): {advice}"
        )
    if not KINDS[fmt].has_camera:
        raise ParameterError(
            f"{flag}: sessions are for bags; {path} is a log of odometry and place recognition "
            f"({fmt}): {advice}"
        )


def check_companions(kind: str, loops: Path | None, ground_truth: Path | None) -> None:
    """Refuse a loop or ground-truth file given for an input kind that does not take it.

    Raises:
        ParameterError: one line saying which option belongs to which input.

    """
    if kind == "bag" and (loops is not None or ground_truth is not None):
        raise ParameterError(
            "--loops and --ground-truth belong to logs; a bag's ground truth is a topic "
            "(--gt-topic)"
        )
    if kind == "tuc" and loops is not None:
        raise ParameterError("--loops belongs to CSV logs; a TUC input file holds its loops")


@dataclass(frozen=True)
class CameraOptions:
    """How to read a camera (bags, videos, image folders).

    Attributes:
        odometry: a bag's motion: ``auto`` (its odometry topic, else the camera's), ``wheel``
            or ``visual`` (RatSLAM's visual odometry); videos and image folders are always
            ``visual``.
        fps: frame rate of a video or image folder without a times file.
        frontend: the visual odometry's settings (None: the input's profile or the defaults).

    """

    odometry: str = "auto"
    fps: float | None = None
    frontend: FrontEndConfig | None = None


Source = BagReader | LogReader | CameraReader
"""A reader of any kind: ``info`` (``duration``, ``frame_count``), ``frames(start_time)``,
``counters``, ``warnings`` and ``close()`` (a context manager:
:class:`~cogmap_core.input_reader.InputReader`)."""


def detect_format(path: str | Path) -> str:
    """The kind of input at ``path``: ``bag``, ``tuc`` or ``csv`` (module doc).

    Raises:
        InputFileError: missing or empty file, or content of no known kind.

    """
    path = Path(path)
    if path.is_dir():
        is_ros2 = (path / "metadata.yaml").exists() or any(
            p.suffix.lower() in BAG_SUFFIXES for p in path.iterdir()
        )
        if is_ros2 or not image_files(path):
            return "bag"
        return "images"
    if path.suffix.lower() in BAG_SUFFIXES:
        return "bag"
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return "video"
    if not path.exists():
        raise InputFileError(
            f"{path}: no such file; give a bag, a video, a folder of images, a TUC log or a CSV log"
        )
    try:
        with path.open("rb") as handle:
            head = handle.read(SNIFF_LIMIT)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read it ({exc.strerror})") from None
    if head.startswith(b"#ROSBAG"):
        return "bag"
    whole = len(head) < SNIFF_LIMIT
    first, comments = _first_data_line(head.removeprefix(BOM))
    if first is None:
        if not comments and whole:
            raise InputFileError(f"{path}: the file is empty; nothing to map")
        where = "the file holds" if whole else f"its first {SNIFF_LIMIT >> 20} MiB hold"
        raise InputFileError(f"{path}: {where} only comments and blank lines; nothing to map")
    # the first data line decides (see looks_like_tuc)
    if looks_like_tuc(first.split()[0]):
        return "tuc"
    if looks_like_csv(first):
        return "csv"
    raise InputFileError(
        f"{path}: not a bag, a TUC log or a CSV log (first line {first[:60]!r}); "
        f"give --format {{{','.join(FORMATS)}}} if it is one"
    )


def _first_data_line(head: bytes) -> tuple[str | None, bool]:
    """The first line of ``head`` that is not blank or a comment, and whether a comment came first.

    The line is None when there is none.
    """
    comments = False
    for raw in head.decode("utf-8", errors="replace").splitlines():
        line = raw.strip()
        if line.startswith("#"):
            comments = True
        elif line:
            return line, comments
    return None, comments


def resolve_format(path: str | Path, fmt: str | None) -> str:
    """``fmt`` when given (checked), else the detected format."""
    if fmt is None or fmt == "auto":
        return detect_format(path)
    if fmt not in FORMATS:
        raise ParameterError(f"--format {fmt!r}: choose one of auto, {', '.join(FORMATS)}")
    return fmt


def open_source(
    path: str | Path,
    fmt: str | None = None,
    *,
    topics: BagTopics | None = None,
    image_scale: int = 1,
    log: LogOptions | None = None,
    on_clock_jump: str = "drop",
    on_corrupt: str = "error",
    camera: CameraOptions | None = None,
) -> Source:
    """Open any input for streaming (format detected from the content unless given).

    Args:
        path: the bag or the log's main file.
        fmt: ``bag``, ``tuc``, ``csv`` or None/``auto``.
        topics: bag topics (bags only).
        image_scale: JPEG decode reduction (bags only).
        log: how to read a log (logs only).
        on_clock_jump: where a bag's clock jumps back, ``drop`` or ``stop`` (bags only; see
            :func:`~cogmap_core.datasets.rosbag_reader.open_bag`).
        on_corrupt: a bag corrupt part-way, ``error`` or ``stop`` (bags only).
        camera: where a camera input's motion comes from, its frame rate and the visual
            odometry's settings (bags, videos, image folders).

    Raises:
        CogmapError: the input cannot be read (one line naming the problem).

    """
    kind = resolve_format(path, fmt)
    log = log or LogOptions()
    camera = camera or CameraOptions()
    check_companions(kind, log.loops, log.ground_truth)
    if kind in ("video", "images") and camera.odometry == "wheel":
        raise ParameterError(f"--odometry wheel: {path} is camera only ({kind}); it has none")
    frontend = camera.frontend
    if frontend is None and kind in ("bag", "video", "images"):
        frontend = frontend_config_for(path)
    if kind == "bag":
        return open_bag(
            path,
            topics=topics,
            image_scale=image_scale,
            on_clock_jump=on_clock_jump,
            on_corrupt=on_corrupt,
            odometry=camera.odometry,
            frontend=frontend,
        )
    if kind == "video":
        return open_video(path, camera.fps, frontend)
    if kind == "images":
        return open_image_folder(path, camera.fps, frontend)
    if kind == "tuc":
        data = read_tuc(path, log.ground_truth, log.use_ground_truth)
    else:
        data = read_odometry_csv(path, log.loops, log.ground_truth, log.use_ground_truth)
    return LogReader(data, log.config)


def input_map_params(kind: InputKind, source: Source) -> MapParams:
    """The default map parameters of an opened input.

    Its kind's; a log's with its own odometry scale, measured from its loop candidates
    (:attr:`LogReader.map_params`).
    """
    if isinstance(source, LogReader):
        return source.map_params
    return kind.map_params
