"""Reading a bag's messages: stamps, ground-truth poses, and the ROS1 header check.

Helpers of :class:`~cogmap_core.datasets.rosbag_reader.BagReader`.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

from cogmap_core.datasets.errors import BagError

ROS1_MAGIC = b"#ROSBAG V2.0\n"


def yaw_of(q: Any) -> float:
    """The yaw of quaternion ``q`` (rad)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def wrap_angle(a: float) -> float:
    """``a`` wrapped into [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def stamp_ns(msg: Any, record_ns: int) -> int:
    """A message's header stamp (ns), or its record time when it has none (or zero)."""
    header = getattr(msg, "header", None)
    if header is None:
        return record_ns
    ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return ns if ns > 0 else record_ns


def ground_truth_pose(msg: Any, msgtype: str) -> tuple[float, float, float]:
    """(x, y, theta) of a ground-truth message of any of the accepted types."""
    if msgtype == "geometry_msgs/msg/Pose2D":
        return float(msg.x), float(msg.y), float(msg.theta)
    if msgtype == "geometry_msgs/msg/Pose":
        pose = msg
    elif msgtype == "geometry_msgs/msg/PoseStamped":
        pose = msg.pose
    else:  # PoseWithCovarianceStamped, Odometry
        pose = msg.pose.pose
    return float(pose.position.x), float(pose.position.y), wrap_angle(yaw_of(pose.orientation))


def interpolate_pose(
    t: float, a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> tuple[float, float, float]:
    """The pose at ``t`` between timed poses ``a`` and ``b`` (clamped to them)."""
    ta, xa, ya, tha = a
    tb, xb, yb, thb = b
    alpha = 0.0 if tb <= ta else min(1.0, max(0.0, (t - ta) / (tb - ta)))
    theta = wrap_angle(tha + alpha * wrap_angle(thb - tha))
    return xa + alpha * (xb - xa), ya + alpha * (yb - ya), theta


def check_ros1_header(path: Path) -> None:
    """Diagnose truncated / unindexed ROS1 bags precisely before rosbags reads them."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(4096 + 13)
    body = head[len(ROS1_MAGIC) :]
    if len(body) < 4:
        raise BagError(f"{path} is truncated (only {size} bytes); copy or record it again")
    (hlen,) = struct.unpack_from("<I", body, 0)
    fields_: dict[bytes, bytes] = {}
    pos = 4
    end = min(4 + hlen, len(body))
    while pos + 4 <= end:
        (flen,) = struct.unpack_from("<I", body, pos)
        item = body[pos + 4 : pos + 4 + flen]
        pos += 4 + flen
        name, _, value = item.partition(b"=")
        fields_[name] = value
    index_pos_raw = fields_.get(b"index_pos")
    if index_pos_raw is None or len(index_pos_raw) != 8:
        raise BagError(f"{path} has a damaged bag header; it is corrupt, copy it again")
    (index_pos,) = struct.unpack("<Q", index_pos_raw)
    if index_pos == 0:
        raise BagError(
            f"{path} has no index (the recording was not closed properly); reindex it with "
            "'rosbag reindex' or record it again"
        )
    if index_pos >= size:
        raise BagError(
            f"{path} is truncated: its index starts at byte {index_pos} but the file has only "
            f"{size} bytes; copy it again"
        )


__all__ = [
    "ROS1_MAGIC",
    "check_ros1_header",
    "ground_truth_pose",
    "interpolate_pose",
    "stamp_ns",
    "wrap_angle",
    "yaw_of",
]
