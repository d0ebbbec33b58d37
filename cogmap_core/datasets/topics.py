"""Topic names and message types of the iRat 2011 Australia bag (OpenRatSLAM ``config_irataus``)."""

from __future__ import annotations

from dataclasses import dataclass

IMAGE_TOPIC = "/irat_red/camera/image/compressed"
ODOMETRY_TOPIC = "/irat_red/odom"
GROUND_TRUTH_TOPIC = "/overhead/pose"

IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
#: Ground truth of the real bag (converted copies of ``irat_aus_28112011`` carry PoseStamped).
GROUND_TRUTH_TYPE = "geometry_msgs/msg/PoseStamped"
#: Ground-truth message types the reader accepts.
GROUND_TRUTH_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/Pose",
    "geometry_msgs/msg/Pose2D",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)


@dataclass(frozen=True, slots=True)
class BagTopics:
    """Which topics hold the camera, the odometry and (optionally) the ground truth.

    Attributes:
        image: ``sensor_msgs/CompressedImage`` topic.
        odometry: ``nav_msgs/Odometry`` topic (``twist.linear.x``, ``twist.angular.z``).
        ground_truth: pose topic, or ``None`` to ignore ground truth.

    """

    image: str = IMAGE_TOPIC
    odometry: str = ODOMETRY_TOPIC
    ground_truth: str | None = GROUND_TRUTH_TOPIC
