"""Writing iRat-layout ROS1 bags with rosbags (no ROS installation needed).

The bag is written under a temporary name next to the target (``.<name>.partial-<pid>``) and
renamed when it is complete, so an interrupted run never leaves a half-written bag under the
final name; such leftovers of killed processes are removed by the next writer of that name.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag1 import Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from cogmap_core.datasets.errors import BagError
from cogmap_core.datasets.topics import (
    GROUND_TRUTH_TYPE,
    IMAGE_TYPE,
    ODOMETRY_TYPE,
    BagTopics,
)
from cogmap_core.fileio import partial_name, remove_stale

_TYPESTORE = get_typestore(Stores.ROS1_NOETIC)
_T = _TYPESTORE.types
_ZERO36 = np.zeros(36, dtype=np.float64)


def ros1_typestore() -> Any:
    """The ROS1 Noetic type store used for writing (message classes in ``.types``)."""
    return _TYPESTORE


def _time(stamp_ns: int) -> Any:
    return _T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)


def _quaternion(theta: float) -> Any:
    return _T["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(theta / 2.0), w=math.cos(theta / 2.0)
    )


def _pose(x: float, y: float, theta: float) -> Any:
    point = _T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
    return _T["geometry_msgs/msg/Pose"](position=point, orientation=_quaternion(float(theta)))


class IratBagWriter:
    """Writes camera, odometry and ground-truth messages in the iRat bag layout.

    Use as a context manager; messages should be written in time order (the reader copes with
    any order, but time order keeps chunks contiguous and reading fast)::

        with IratBagWriter(path) as bag:
            bag.write_odometry(stamp_ns, v, w)
            bag.write_image(stamp_ns, jpeg_bytes)
    """

    def __init__(
        self,
        path: str | Path,
        *,
        topics: BagTopics | None = None,
        overwrite: bool = False,
        frame_ids: tuple[str, str, str] = ("irat_red/camera", "irat_red/odom", "overhead"),
    ) -> None:
        """Prepare to write ``path`` (created under a temporary name until :meth:`close`).

        Raises:
            BagError: the target is a folder, exists and ``overwrite`` is false, or cannot be
                created.

        """
        self.path = Path(path)
        self.topics = topics or BagTopics()
        if self.path.is_dir():  # would fail only at the rename, after all the writing
            raise BagError(f"{self.path} is a folder; give the path of the .bag file to write")
        if self.path.exists() and not overwrite:
            raise BagError(
                f"{self.path} already exists; choose another name or overwrite it (--force)"
            )
        if not self.path.parent.is_dir():
            raise BagError(f"folder {self.path.parent} does not exist; create it first")
        remove_stale(self.path.parent, f".{self.path.name}.partial-*")  # of killed writers
        self._tmp = self.path.with_name(partial_name(self.path.name))
        if self._tmp.exists():
            self._tmp.unlink()
        self._writer = Writer(self._tmp)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"cannot create {self.path}: {exc}; check the folder") from None
        self._connections: dict[str, Connection] = {}
        self._seq: dict[str, int] = {}
        self._frame_ids = frame_ids
        self._closed = False
        self.counts: dict[str, int] = {}

    # ------------------------------------------------------------------------------ generic
    def connection(self, topic: str, msgtype: str) -> Connection:
        """The connection for ``topic`` (added on first use with ``msgtype``)."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=_TYPESTORE)
            self._connections[topic] = conn
            self._seq[topic] = 0
            self.counts[topic] = 0
        elif conn.msgtype != msgtype:
            raise BagError(f"topic {topic} already carries {conn.msgtype}, not {msgtype}")
        return conn

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, data: bytes) -> None:
        """Write already serialised (ROS1) message bytes, e.g. to build a deliberately bad bag."""
        conn = self.connection(topic, msgtype)
        self._writer.write(conn, int(stamp_ns), data)
        self.counts[topic] += 1

    def write_message(self, topic: str, stamp_ns: int, message: Any) -> None:
        """Serialise and write a rosbags message object (its type decides the connection)."""
        msgtype = message.__msgtype__
        self.write_raw(topic, msgtype, stamp_ns, _TYPESTORE.serialize_ros1(message, msgtype))

    def header(self, topic: str, stamp_ns: int, frame_id: str) -> Any:
        """A ``std_msgs/Header`` with the topic's next sequence number."""
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        return _T["std_msgs/msg/Header"](seq=seq, stamp=_time(stamp_ns), frame_id=frame_id)

    # ----------------------------------------------------------------------------- iRat topics
    def write_image(
        self, stamp_ns: int, jpeg: bytes, fmt: str = "jpeg", record_ns: int | None = None
    ) -> None:
        """A ``sensor_msgs/CompressedImage`` on the camera topic.

        ``record_ns`` is the bag's record time (default: the header stamp), as for all writers.
        """
        topic = self.topics.image
        self.connection(topic, IMAGE_TYPE)
        msg = _T[IMAGE_TYPE](
            header=self.header(topic, stamp_ns, self._frame_ids[0]),
            format=fmt,
            data=np.frombuffer(jpeg, dtype=np.uint8),
        )
        self.write_message(topic, stamp_ns if record_ns is None else record_ns, msg)

    def write_odometry(
        self,
        stamp_ns: int,
        v: float,
        w: float,
        pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
        record_ns: int | None = None,
    ) -> None:
        """A ``nav_msgs/Odometry``: ``twist.linear.x = v``, ``twist.angular.z = w``.

        ``pose`` is the robot's own dead-reckoned pose (not used by the reader).
        """
        topic = self.topics.odometry
        vec = _T["geometry_msgs/msg/Vector3"]
        twist = _T["geometry_msgs/msg/Twist"](
            linear=vec(x=float(v), y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=float(w))
        )
        msg = _T[ODOMETRY_TYPE](
            header=self.header(topic, stamp_ns, self._frame_ids[1]),
            child_frame_id="irat_red/base_link",
            pose=_T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(*pose), covariance=_ZERO36),
            twist=_T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=_ZERO36),
        )
        self.write_message(topic, stamp_ns if record_ns is None else record_ns, msg)

    def write_ground_truth(
        self, stamp_ns: int, x: float, y: float, theta: float, record_ns: int | None = None
    ) -> None:
        """A ``geometry_msgs/PoseStamped`` on the ground-truth topic."""
        topic = self.topics.ground_truth
        if topic is None:
            raise BagError("this writer has no ground-truth topic; set BagTopics.ground_truth")
        msg = _T[GROUND_TRUTH_TYPE](
            header=self.header(topic, stamp_ns, self._frame_ids[2]), pose=_pose(x, y, theta)
        )
        self.write_message(topic, stamp_ns if record_ns is None else record_ns, msg)

    # ------------------------------------------------------------------------------ finishing
    def close(self) -> Path:
        """Finish the bag and move it to its final name; returns the path."""
        if self._closed:
            return self.path
        self._closed = True
        try:
            self._writer.close()
            os.replace(self._tmp, self.path)
        except (WriterError, OSError) as exc:
            self._tmp.unlink(missing_ok=True)
            raise BagError(f"cannot finish {self.path}: {exc}; check free disk space") from None
        return self.path

    def abort(self) -> None:
        """Stop writing and delete the temporary file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except (WriterError, OSError):
            pass
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> IratBagWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
