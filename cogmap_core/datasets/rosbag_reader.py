"""Streaming reader for iRat-layout bags (ROS1, and ROS2 where rosbags can), pure rosbags.

:func:`open_bag` checks the bag and its topics; :meth:`BagReader.frames` then streams
:class:`~cogmap_core.frames.Frame` objects in time order: the decoded camera image, the
odometry integrated since the previous frame and the ground-truth pose at the frame's time.
The image is grey, or in colour (blue, green, red) when the JPEG is and the front end's
arithmetic averages colour as OpenRatSLAM does
(:func:`~cogmap_core.frontend.local_view.averages_colour`: its default); a grey JPEG is
always decoded grey, and so is a colour one with ``vt_whole_crop = 1`` (its luma).

Conventions (those of OpenRatSLAM):

- data time is the message header stamp (the bag's record time when a stamp is zero);
  ``Frame.time`` counts seconds from the bag's first message;
- odometry: each message contributes ``twist.linear.x * dt`` and ``twist.angular.z * dt`` with
  ``dt`` the header-stamp interval to the previous odometry message; a frame gets everything
  recorded since the previous frame, up to and including its own record time (the first
  message only starts the clock);
- ground truth: interpolated between the two poses around the frame time when they are at most
  1 s apart, else the nearest pose within 0.25 s, else ``None``.

Bad data never raises a traceback. The policy, counted in :attr:`BagReader.counters` and
summarised by :attr:`BagReader.warnings`:

- undecodable JPEG, JPEG that decodes but with libjpeg's "Corrupt JPEG data" / "Premature end
  of JPEG file" warnings (a scrambled image, see :mod:`.jpeg`), image of another size than the
  first, image whose header declares more than :data:`~.jpeg.MAX_IMAGE_PIXELS` pixels (not
  decoded), undeserialisable message: skipped (the odometry carries over to the next frame);
- a clock that jumps back (ROS1): the bag's record times are checked in the order the messages
  were written; where a topic's record time goes back more than
  :data:`CLOCK_JUMP_TOLERANCE`, the two stretches would interleave in time order. With
  ``on_clock_jump="drop"`` (default) the messages written after the jump are dropped until that
  topic's time passes the time it had reached (the overlap); with ``"stop"`` reading ends at the
  jump. Either way the jump, its size and the messages dropped are counted and warned about
  when the bag is opened (:attr:`BagReader.open_warnings`). Header stamps that go back while
  the record time does not are handled per topic (below);
- image stamp earlier than the previous frame's: frame skipped (frame times never decrease);
- odometry with NaN/inf velocity: skipped (the next message covers its interval);
- odometry stamp earlier than the previous one: skipped; after three in a row the clock is taken
  to have been reset and integration restarts from the new stamps; odometry stamp more than
  ``max_odometry_gap`` after the previous: that interval contributes nothing (motion unknown);
- ground truth NaN/inf or going backwards: skipped; a ground-truth topic that is not a pose type:
  read without ground truth, with a warning (:attr:`BagReader.open_warnings`).

Camera only: with ``odometry="visual"``, or ``"auto"`` (the default) on a bag without the
odometry topic, the odometry topic is not read and each frame's motion comes from the camera,
as RatSLAM's visual odometry computes it (:mod:`cogmap_core.frontend.visual_odometry`, with the
front end's settings).

Errors (:class:`BagError` and subclasses, one line each): missing file, not a bag, truncated,
unindexed or corrupt bag, missing camera or odometry topic (listing the topics present), wrong
camera or odometry message type, a bag none of whose images decode. A bag that turns out corrupt
part-way raises when the damage is reached, unless ``on_corrupt="stop"``: the pass then ends
there (counted as ``corrupt_chunks`` with its time) and the frames read so far stand.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection

from cogmap_core.datasets.bag_messages import (
    ROS1_MAGIC,
    check_ros1_header,
    ground_truth_pose,
    interpolate_pose,
    stamp_ns,
)
from cogmap_core.datasets.clock_jumps import CLOCK_JUMP_POLICIES, ClockJump, plan_clock_jumps
from cogmap_core.datasets.errors import BagError, BagMessageTypeError, BagTopicError
from cogmap_core.datasets.jpeg import MAX_IMAGE_PIXELS, ImageTooLarge, JpegDecoder
from cogmap_core.datasets.read_counters import DESCRIBED_AT_OPEN, ReadCounters
from cogmap_core.datasets.topics import (
    GROUND_TRUTH_TYPES,
    IMAGE_TYPE,
    ODOMETRY_TYPE,
    BagTopics,
)
from cogmap_core.errors import ParameterError
from cogmap_core.frames import Frame
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import averages_colour
from cogmap_core.frontend.visual_odometry import with_visual_odometry
from cogmap_core.input_reader import InputReader

log = logging.getLogger(__name__)

#: Where a bag's motion comes from: its odometry topic, the camera, or the topic when present.
ODOMETRY_SOURCES = ("auto", "wheel", "visual")

#: A decoded frame waiting for its ground truth: time, image, translation, rotation and the
#: odometry steps (one row per message).
_FrameData = tuple[float, NDArray[np.uint8], float, float, NDArray[np.float64]]

_DECODE_FLAGS = {
    1: cv2.IMREAD_GRAYSCALE,
    2: cv2.IMREAD_REDUCED_GRAYSCALE_2,
    4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
    8: cv2.IMREAD_REDUCED_GRAYSCALE_8,
}
#: Colour JPEGs when the front end averages colour (blue, green, red, as ``bgr8``).
_COLOUR_FLAGS = {
    1: cv2.IMREAD_COLOR,
    2: cv2.IMREAD_REDUCED_COLOR_2,
    4: cv2.IMREAD_REDUCED_COLOR_4,
    8: cv2.IMREAD_REDUCED_COLOR_8,
}
_GT_INTERPOLATION_GAP = 1.0  # s
_GT_HOLD = 0.25  # s
_CLOCK_RESET_AFTER = 3
_START_MARGIN = 2.0  # s of data read before start_time (odometry clock, ground truth)
CORRUPT_DATA_POLICIES = ("error", "stop")


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds.

    Attributes:
        path: the bag.
        ros_version: 1 or 2.
        duration: seconds between the first and the last message.
        frame_count: camera messages (frames actually yielded may be fewer).
        odometry_count: odometry messages.
        ground_truth_count: ground-truth messages (0 without ground truth).
        has_ground_truth: whether the ground-truth topic exists with a usable type.
        topics: every topic in the bag -> its message type.
        image_topic, odometry_topic, ground_truth_topic: the topics used.
        ground_truth_type: message type of the ground truth (``None`` without).

    """

    path: Path
    ros_version: int
    duration: float
    frame_count: int
    odometry_count: int
    ground_truth_count: int
    has_ground_truth: bool
    topics: dict[str, str]
    image_topic: str
    odometry_topic: str
    ground_truth_topic: str | None
    ground_truth_type: str | None

    @property
    def frame_rate(self) -> float:
        """Mean camera rate (Hz)."""
        return self.frame_count / self.duration if self.duration > 0 else 0.0


class BagReader(InputReader):
    """An open bag with the iRat topics; iterate :meth:`frames` (one pass at a time)."""

    def __init__(
        self,
        path: str | Path,
        topics: BagTopics | None = None,
        image_scale: int = 1,
        max_odometry_gap: float = 1.0,
        on_clock_jump: str = "drop",
        on_corrupt: str = "error",
        odometry: str = "auto",
        frontend: FrontEndConfig | None = None,
    ) -> None:
        """Open and check the bag; see :func:`open_bag`."""
        if odometry not in ODOMETRY_SOURCES:
            raise ParameterError(
                f"odometry {odometry!r} is not one of {', '.join(ODOMETRY_SOURCES)}"
            )
        self.odometry = odometry
        self.frontend = frontend
        #: whether colour JPEGs are decoded in colour (the front end averages blue, green, red)
        self.colour = averages_colour(frontend)
        #: whether the frames' motion comes from the camera (decided when the bag is checked)
        self.visual_odometry = odometry == "visual"
        self._tmpdir: Path | None = None
        self._reader: AnyReader | None = None
        topics = topics or BagTopics()
        if len({topics.image, topics.odometry, topics.ground_truth}) < 3:
            raise ParameterError(
                f"camera, odometry and ground-truth topics must differ (got {topics.image}, "
                f"{topics.odometry}, {topics.ground_truth})"
            )
        if image_scale not in _DECODE_FLAGS:
            raise ParameterError(f"image_scale {image_scale} is not supported; use 1, 2, 4 or 8")
        if not (max_odometry_gap > 0):
            raise ParameterError(f"max_odometry_gap {max_odometry_gap} must be > 0 s")
        if on_clock_jump not in CLOCK_JUMP_POLICIES:
            raise ParameterError(f"on_clock_jump {on_clock_jump!r} is not 'drop' or 'stop'")
        if on_corrupt not in CORRUPT_DATA_POLICIES:
            raise ParameterError(f"on_corrupt {on_corrupt!r} is not 'error' or 'stop'")
        self.on_clock_jump = on_clock_jump
        self.on_corrupt = on_corrupt
        self.clock_jumps: list[ClockJump] = []
        self.path = Path(path)
        self.topics = topics
        self.image_scale = image_scale
        self.max_odometry_gap = float(max_odometry_gap)
        self.counters = ReadCounters()
        self.open_warnings: list[str] = []
        self._iterating = False
        self._reader = self._open_reader()
        try:
            self.info = self._inspect()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------------------ opening
    def _open_reader(self) -> AnyReader:
        path = self.path
        if not path.exists():
            raise BagError(f"bag {path} does not exist; check the path")
        ros_paths: list[Path]
        if path.is_dir():
            if not (path / "metadata.yaml").exists():
                raise BagError(
                    f"{path} is a folder but not a ROS2 bag (no metadata.yaml); give a .bag file "
                    "or a ROS2 bag folder"
                )
            ros_paths = [path]
        else:
            try:
                with path.open("rb") as fh:
                    magic = fh.read(len(ROS1_MAGIC))
            except OSError as exc:
                raise BagError(f"cannot read {path}: {exc.strerror}; check permissions") from None
            if not magic:
                raise BagError(f"{path} is empty; record or generate the bag again")
            if magic == ROS1_MAGIC:
                check_ros1_header(path)
                if path.suffix == ".bag":
                    ros_paths = [path]
                else:  # rosbags recognises ROS1 bags by their suffix
                    self._tmpdir = Path(tempfile.mkdtemp(prefix="cogmap-bag-"))
                    link = self._tmpdir / (path.name + ".bag")
                    link.symlink_to(path.resolve())
                    ros_paths = [link]
            elif magic.startswith(b"#ROSBAG"):
                version = magic.split(b"\n")[0].decode("ascii", "replace")
                raise BagError(
                    f"{path} is a '{version}' bag; only ROS1 bag format 2.0 is supported"
                )
            elif path.suffix in (".mcap", ".db3"):
                ros_paths = [path]
            else:
                raise BagError(
                    f"{path} is not a ROS bag (no '#ROSBAG V2.0' header and not a ROS2 bag); "
                    "give a .bag file"
                )
        try:
            reader = AnyReader(ros_paths)
            reader.open()
        except Exception as exc:  # rosbags raises many kinds on damaged files
            self._cleanup_tmp()
            detail = " ".join(str(exc).split()) or type(exc).__name__
            raise BagError(
                f"cannot read bag {path}: {detail}; it is damaged or truncated, copy it again"
            ) from None
        return reader

    def _inspect(self) -> BagInfo:
        reader = self._require_reader()
        all_topics = {name: (info.msgtype or "?") for name, info in reader.topics.items()}
        listing = ", ".join(f"{t} ({m})" for t, m in sorted(all_topics.items())) or "no topics"

        def need(topic: str, msgtype: str, what: str) -> None:
            if topic not in all_topics:
                raise BagTopicError(
                    f"bag {self.path} has no {what} topic {topic}; it has: {listing}; "
                    "choose the topic names to read"
                )
            if all_topics[topic] != msgtype:
                raise BagMessageTypeError(
                    f"topic {topic} in {self.path} carries {all_topics[topic]}, but the {what} "
                    f"must be {msgtype}; choose the right topic"
                )

        need(self.topics.image, IMAGE_TYPE, "camera")
        if self.odometry == "wheel" or (
            self.odometry == "auto" and self.topics.odometry in all_topics
        ):
            need(self.topics.odometry, ODOMETRY_TYPE, "odometry")
        else:
            self.visual_odometry = True
        gt_topic = self.topics.ground_truth
        gt_type: str | None = None
        if gt_topic is not None and gt_topic in all_topics:
            gt_type = all_topics[gt_topic]
            if gt_type not in GROUND_TRUTH_TYPES:  # optional data: warn and go on without it
                note = (
                    f"ground-truth topic {gt_topic} carries {gt_type}, not a pose type "
                    f"({', '.join(t.split('/')[-1] for t in GROUND_TRUTH_TYPES)}); reading "
                    "without ground truth"
                )
                self.open_warnings.append(note)
                log.warning("%s", note)
                gt_type = None
        self._conns: dict[str, list[Connection]] = {}
        for conn in reader.connections:
            self._conns.setdefault(conn.topic, []).append(conn)
        counts = {t: sum(c.msgcount for c in cs) for t, cs in self._conns.items()}
        if counts.get(self.topics.image, 0) == 0:
            raise BagError(f"camera topic {self.topics.image} in {self.path} has no messages")
        self._gt_type = gt_type
        # at equal record times rosbags yields messages in this order: odometry, ground truth,
        # then the image, so odometry stamped at a frame's time belongs to that frame
        wheel = [] if self.visual_odometry else [self.topics.odometry]
        self._used = [*wheel, *([gt_topic] if gt_type else []), self.topics.image]
        self._t0_ns = self._first_stamp_ns()
        self._handle_clock_jumps()
        return BagInfo(
            path=self.path,
            ros_version=2 if reader.is2 else 1,
            duration=reader.duration / 1e9,
            frame_count=counts.get(self.topics.image, 0),
            odometry_count=counts.get(self.topics.odometry, 0),
            ground_truth_count=counts.get(gt_topic, 0) if gt_type and gt_topic else 0,
            has_ground_truth=gt_type is not None and counts.get(gt_topic or "", 0) > 0,
            topics=all_topics,
            image_topic=self.topics.image,
            odometry_topic=self.topics.odometry,
            ground_truth_topic=gt_topic if gt_type else None,
            ground_truth_type=gt_type,
        )

    def _first_stamp_ns(self) -> int:
        """The bag's start: its first record time, or an earlier first stamp of a used topic."""
        reader = self._require_reader()
        t0 = int(reader.start_time)
        for topic in self._used:
            for conn in self._conns.get(topic, []):
                gen = reader.messages(connections=[conn])
                try:
                    for c, rec, raw in gen:
                        try:
                            msg = reader.deserialize(raw, c.msgtype)
                        except Exception:
                            break
                        t0 = min(t0, stamp_ns(msg, rec))
                        break
                except Exception as exc:
                    raise self._corrupt(exc, None) from None
                finally:
                    gen.close()
        return t0

    def _handle_clock_jumps(self) -> None:
        """Find record-clock jumps back (ROS1, write order) and drop or cut what follows."""
        connections = [c for t in self._used for c in self._conns.get(t, [])]
        plan = plan_clock_jumps(connections, self.on_clock_jump, self._t0_ns)
        if plan is None:
            return
        self.clock_jumps = plan
        first = plan[0]
        dropped = sum(j.dropped for j in plan)
        times = f"{len(plan)} times, first " if len(plan) > 1 else ""
        if self.on_clock_jump == "stop":
            what = f"reading stops there ({dropped} later messages not read)"
        else:
            what = (
                f"{dropped} messages recorded again over the same time were dropped (each topic "
                "resumes when its clock passes the time it had reached)"
            )
        note = (
            f"the bag's clock jumps back {times}{first.back:.2f} s at t={first.time:.2f} s: {what}"
        )
        self.open_warnings.append(note)
        log.warning("%s", note)

    def _require_reader(self) -> AnyReader:
        if self._reader is None:
            raise BagError(f"bag {self.path} is closed; open it again")
        return self._reader

    def _corrupt(self, exc: BaseException, t: float | None, stopped: bool = False) -> BagError:
        where = f" near t={t:.2f} s" if t is not None else ""
        detail = " ".join(str(exc).split()) or type(exc).__name__
        if stopped:
            return BagError(f"bag {self.path} is corrupt{where} ({detail}); read up to there")
        advice = "copy it again, or read up to there (cogmap run --until-error)"
        if t is None:
            advice = "copy it again"
        return BagError(f"bag {self.path} is corrupt{where} ({detail}); {advice}")

    # ------------------------------------------------------------------------------- access
    @property
    def warnings(self) -> list[str]:
        """Problems found when opening, then those met in the last pass (empty when clean)."""
        return self.open_warnings + self.counters.warnings()

    @property
    def start_stamp(self) -> float:
        """Absolute stamp (s) that ``Frame.time`` counts from."""
        return self._t0_ns / 1e9

    def frames(self, start_time: float = 0.0) -> Iterator[Frame]:
        """Stream frames in time order, from data time ``start_time`` (s) on.

        Memory stays flat in the bag's length: messages are read chunk by chunk and only about
        a second of frames waits for the ground truth that brackets it. Counters of this pass
        are in :attr:`counters`.

        Raises:
            BagError: the bag is corrupt past the point already read, or no image decodes.
            ParameterError: ``start_time`` outside the bag.

        """
        if not (0.0 <= start_time <= self.info.duration + 1.0) or not math.isfinite(start_time):
            raise ParameterError(
                f"start time {start_time} s is outside the bag (0-{self.info.duration:.1f} s)"
            )
        if self._iterating:
            raise BagError(f"bag {self.path} is already being read; finish that pass first")
        if self.visual_odometry:
            return with_visual_odometry(self._frames(start_time), self.frontend)
        return self._frames(start_time)

    def _frames(self, start_time: float) -> Iterator[Frame]:
        reader = self._require_reader()
        self._iterating = True
        counters = ReadCounters()
        if self.clock_jumps:
            counters.clock_jumps = len(self.clock_jumps)
            counters.clock_jump_messages_dropped = sum(j.dropped for j in self.clock_jumps)
            for name in DESCRIBED_AT_OPEN:
                counters.first_seen[name] = self.clock_jumps[0].time
        self.counters = counters
        topics = self.topics
        image_topic, odom_topic = topics.image, topics.odometry
        gt_topic = topics.ground_truth if self._gt_type else None
        gt_type = self._gt_type or ""
        colour_flag = _COLOUR_FLAGS[self.image_scale] if self.colour else None
        decoder = JpegDecoder(_DECODE_FLAGS[self.image_scale], colour_flag)
        t0 = self._t0_ns
        max_gap_ns = int(self.max_odometry_gap * 1e9)
        start_ns = t0 + int(start_time * 1e9)
        read_from = start_ns - int(_START_MARGIN * 1e9) if start_time > _START_MARGIN else None
        connections = [c for t in self._used for c in self._conns.get(t, [])]

        odom_prev: int | None = None
        backwards_run = 0
        trans = rot = 0.0
        steps: list[tuple[float, float]] = []  # the same, message by message
        last_image_ns: int | None = None
        shape: tuple[int, ...] | None = None
        gt_prev: tuple[float, float, float, float] | None = None
        pending: deque[_FrameData] = deque()
        images_seen = images_decoded = 0
        largest: tuple[int, int] | None = None  # the first oversized image's declared size
        index = 0
        now = 0.0

        def release(frame_data: _FrameData, pose: Any) -> Frame:
            nonlocal index
            t, image, tr, ro, odometry_steps = frame_data
            if pose is None and gt_topic is not None:
                counters.note("frames_without_ground_truth", t)
            frame = Frame(
                index=index,
                time=t,
                image=image,
                translation=tr,
                rotation=ro,
                ground_truth=pose,
                odometry_steps=odometry_steps,
            )
            index += 1
            counters.frames += 1
            return frame

        def held(t: float) -> tuple[float, float, float] | None:
            if gt_prev is not None and abs(t - gt_prev[0]) <= _GT_HOLD:
                return gt_prev[1], gt_prev[2], gt_prev[3]
            return None

        messages = reader.messages(connections=connections, start=read_from)
        try:
            while True:
                try:
                    item = next(messages, None)
                except Exception as exc:  # damaged chunk or record
                    if self.on_corrupt != "stop":
                        raise self._corrupt(exc, now) from None
                    counters.note("corrupt_chunks", now)
                    log.warning("%s", self._corrupt(exc, now, stopped=True))
                    break
                if item is None:
                    break
                conn, record_ns, raw = item
                topic = conn.topic
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception:
                    counters.note("corrupt_messages", (record_ns - t0) / 1e9)
                    continue
                stamp = stamp_ns(msg, record_ns)
                now = (stamp - t0) / 1e9

                if topic == odom_topic:
                    twist = msg.twist.twist
                    v, w = float(twist.linear.x), float(twist.angular.z)
                    if not (math.isfinite(v) and math.isfinite(w)):
                        counters.note("nonfinite_odometry", now)
                        continue
                    if odom_prev is None:
                        odom_prev = stamp
                        continue
                    dt_ns = stamp - odom_prev
                    if dt_ns < 0:
                        counters.note("odometry_stamps_backwards", now)
                        backwards_run += 1
                        if backwards_run >= _CLOCK_RESET_AFTER:
                            counters.note("odometry_clock_resets", now)
                            odom_prev = stamp
                            backwards_run = 0
                        continue
                    backwards_run = 0
                    odom_prev = stamp
                    if dt_ns > max_gap_ns:
                        counters.note("odometry_gaps", now)
                        continue
                    dt = dt_ns / 1e9
                    trans += v * dt
                    rot += w * dt
                    steps.append((v * dt, w * dt))

                elif topic == image_topic:
                    if stamp < start_ns:  # before the requested start: consume, do not decode
                        trans = rot = 0.0
                        steps = []
                        last_image_ns = stamp
                        continue
                    images_seen += 1
                    if last_image_ns is not None and stamp < last_image_ns:
                        counters.note("image_stamps_backwards", now)
                        continue
                    data = np.asarray(msg.data, dtype=np.uint8)
                    try:
                        image, damage = decoder.decode(data) if data.size else (None, None)
                    except ImageTooLarge as exc:  # refused from its header, never allocated
                        counters.note("oversized_images", now)
                        largest = largest or (exc.width, exc.height)
                        continue
                    if image is None:
                        counters.note("undecodable_images", now)
                        continue
                    images_decoded += 1
                    if damage is not None:
                        counters.note("corrupt_images", now)
                        continue
                    if shape is None:  # (height, width): grey and colour frames may mix
                        shape = image.shape[:2]
                    elif image.shape[:2] != shape:
                        counters.note("image_size_changes", now)
                        continue
                    last_image_ns = stamp
                    frame_data = (now, image, trans, rot, np.array(steps).reshape(-1, 2))
                    trans = rot = 0.0
                    steps = []
                    if gt_topic is None:
                        yield release(frame_data, None)
                    else:
                        pending.append(frame_data)

                elif topic == gt_topic:
                    x, y, th = ground_truth_pose(msg, gt_type)
                    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
                        counters.note("nonfinite_ground_truth", now)
                        continue
                    if gt_prev is not None and now < gt_prev[0]:
                        counters.note("ground_truth_stamps_backwards", now)
                        continue
                    current = (now, x, y, th)
                    while pending and pending[0][0] <= now:
                        fd = pending.popleft()
                        if gt_prev is not None and now - gt_prev[0] <= _GT_INTERPOLATION_GAP:
                            pose = interpolate_pose(fd[0], gt_prev, current)
                        elif now - fd[0] <= _GT_HOLD:
                            pose = (x, y, th)
                        else:
                            pose = held(fd[0])
                        yield release(fd, pose)
                    gt_prev = current

                # frames that can no longer get a bracketing ground truth
                while pending and pending[0][0] < now - _GT_INTERPOLATION_GAP:
                    fd = pending.popleft()
                    yield release(fd, held(fd[0]))
            while pending:
                fd = pending.popleft()
                yield release(fd, held(fd[0]))
            if images_seen and counters.oversized_images == images_seen and largest:
                raise BagError(
                    f"all {images_seen} camera images in {self.path} are larger than the "
                    f"{MAX_IMAGE_PIXELS:,} pixels cogmap decodes (the first declares "
                    f"{largest[0]} x {largest[1]}); check the camera topic"
                )
            if images_seen and not images_decoded:
                raise BagError(
                    f"none of the {images_seen} camera images in {self.path} could be decoded as "
                    "JPEG; check the camera topic"
                )
        finally:
            messages.close()
            decoder.close()
            self._iterating = False

    # ------------------------------------------------------------------------------ closing
    def _cleanup_tmp(self) -> None:
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def close(self) -> None:
        """Close the bag (idempotent)."""
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:  # already closed or half open
                pass
            self._reader = None
        self._cleanup_tmp()

    def __del__(self) -> None:
        self._cleanup_tmp()


def open_bag(
    path: str | Path,
    topics: BagTopics | None = None,
    image_scale: int = 1,
    max_odometry_gap: float = 1.0,
    on_clock_jump: str = "drop",
    on_corrupt: str = "error",
    odometry: str = "auto",
    frontend: FrontEndConfig | None = None,
) -> BagReader:
    """Open an iRat-layout bag for streaming.

    Args:
        path: a ROS1 ``.bag`` file (any name) or a ROS2 bag folder / ``.mcap`` / ``.db3``.
        topics: topic names (default: the iRat 2011 Australia bag's).
        image_scale: 1, 2, 4 or 8: decode JPEGs at that reduction (fast DCT-domain scaling);
            images are then ``240/scale x 416/scale`` for iRat frames.
        max_odometry_gap: longer odometry intervals (s) contribute no motion (counted).
        on_clock_jump: ``"drop"`` the messages recorded again after the record clock jumps back
            (default) or ``"stop"`` reading at the first jump (see the module docstring).
        on_corrupt: ``"error"`` (default): damaged data part-way raises :class:`BagError`;
            ``"stop"``: the pass ends there, keeping the frames read so far (counted).
        odometry: ``"wheel"`` (the odometry topic, required), ``"visual"`` (the camera's) or
            ``"auto"`` (the topic when the bag has it, else the camera's).
        frontend: the front end's settings the frames are for: the visual odometry's, and
            whether colour JPEGs are decoded in colour (OpenRatSLAM's arithmetic, the default)
            or as their luma (``vt_whole_crop = 1``). Default: the iRat defaults.

    Raises:
        BagError: missing file, not a bag, truncated / unindexed / corrupt bag.
        BagTopicError: a required topic is missing (the message lists those present).
        BagMessageTypeError: the camera or odometry topic has the wrong message type.
        ParameterError: bad ``image_scale``, ``max_odometry_gap`` or policy.

    """
    return BagReader(
        path,
        topics=topics,
        image_scale=image_scale,
        max_odometry_gap=max_odometry_gap,
        on_clock_jump=on_clock_jump,
        on_corrupt=on_corrupt,
        odometry=odometry,
        frontend=frontend,
    )
