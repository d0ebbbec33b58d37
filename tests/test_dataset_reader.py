"""The iRat bag reader: write -> read round trips and every kind of bad input."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets import (
    BagError,
    BagMessageTypeError,
    BagTopicError,
    BagTopics,
    open_bag,
)
from cogmap_core.datasets.bag_writer import IratBagWriter, ros1_typestore
from cogmap_core.errors import ParameterError

T0 = 1_322_449_200 * 10**9  # ns
S = 10**9


def jpeg(index: int, size: tuple[int, int] = (240, 416)) -> bytes:
    """A distinct test image per index."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w]
    img = ((xx * (index + 1) + yy * 3 + index * 17) % 256).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def write_bag(
    path: Path,
    frames: list[tuple[float, bytes]],
    odom: list[tuple[float, float, float]],
    gt: list[tuple[float, float, float, float]] | None = None,
    topics: BagTopics | None = None,
) -> Path:
    """Write messages (times in s from T0) in time order; odometry before images at ties."""
    events: list[tuple[float, int, tuple]] = []
    events += [(t, 0, (v, w)) for t, v, w in odom]
    events += [(t, 1, (x, y, th)) for t, x, y, th in gt or []]
    events += [(t, 2, (data,)) for t, data in frames]
    events.sort(key=lambda e: (e[0], e[1]))
    with IratBagWriter(path, topics=topics) as bag:
        for t, kind, payload in events:
            ns = T0 + round(t * S)
            if kind == 0:
                bag.write_odometry(ns, *payload)
            elif kind == 1:
                bag.write_ground_truth(ns, *payload)
            else:
                bag.write_image(ns, payload[0])
    return path


def simple_bag(path: Path, n: int = 10, gt: bool = True) -> Path:
    """Frames at 0.1 s + k * 0.2 s; odometry every 0.1 s at v = 0.1 k, w = 0.01 k."""
    frames = [(0.1 + 0.2 * k, jpeg(k)) for k in range(n)]
    odom = [(0.1 * k, 0.1 * k, 0.01 * k) for k in range(2 * n + 1)]
    truth = [(0.1 * k, 0.05 * k, -0.02 * k, 0.1 * k) for k in range(2 * n + 2)] if gt else None
    return write_bag(path, frames, odom, truth)


# ----------------------------------------------------------------------------------- round trip
def test_round_trip_images_odometry_ground_truth(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "rt.bag")
    with open_bag(path) as reader:
        info = reader.info
        assert info.frame_count == 10
        assert info.odometry_count == 21
        assert info.ground_truth_count == 22
        assert info.has_ground_truth
        assert info.ground_truth_type == "geometry_msgs/msg/PoseStamped"
        assert info.duration == pytest.approx(2.1)
        frames = list(reader.frames())
        assert reader.warnings == []
    assert [f.index for f in frames] == list(range(10))
    for k, frame in enumerate(frames):
        expected = cv2.imdecode(np.frombuffer(jpeg(k), np.uint8), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(frame.image, expected)
        assert frame.time == pytest.approx(0.1 + 0.2 * k, abs=1e-9)
        # odometry messages in (t_{k-1}, t_k]: each contributes v*dt and w*dt with dt = 0.1 s
        if k == 0:  # the message at 0.0 only starts the clock; the one at 0.1 counts
            msgs = [1]
        else:
            msgs = [2 * k, 2 * k + 1]
        assert frame.translation == pytest.approx(sum(0.1 * m * 0.1 for m in msgs), abs=1e-12)
        assert frame.rotation == pytest.approx(sum(0.01 * m * 0.1 for m in msgs), abs=1e-12)
        # ground truth was written at every 0.1 s, so the frame times hit it exactly
        m = 1 + 2 * k
        x, y, th = frame.ground_truth
        assert (x, y) == pytest.approx((0.05 * m, -0.02 * m), abs=1e-9)
        assert th == pytest.approx(0.1 * m, abs=1e-9)


def test_ground_truth_is_interpolated_between_poses(tmp_path: Path) -> None:
    frames = [(0.25, jpeg(0)), (0.5, jpeg(1))]
    odom = [(0.0, 0.0, 0.0), (0.5, 0.0, 0.0)]
    # heading crosses +-pi between the two poses: interpolation goes the short way
    gt = [(0.0, 0.0, 0.0, 3.0), (1.0, 1.0, 2.0, -3.0)]
    with open_bag(write_bag(tmp_path / "gt.bag", frames, odom, gt)) as reader:
        f0, f1 = list(reader.frames())
    assert f0.ground_truth[:2] == pytest.approx((0.25, 0.5))
    short = 3.0 + 0.25 * (2 * math.pi - 6.0)
    assert f0.ground_truth[2] == pytest.approx(short)
    assert f1.ground_truth[:2] == pytest.approx((0.5, 1.0))
    assert abs(f1.ground_truth[2]) == pytest.approx(math.pi)


def test_ground_truth_far_away_is_none_and_counted(tmp_path: Path) -> None:
    frames = [(0.1, jpeg(0)), (3.0, jpeg(1)), (6.0, jpeg(2))]
    odom = [(0.0, 0.0, 0.0), (6.0, 0.0, 0.0)]
    gt = [(0.0, 0.0, 0.0, 0.0), (5.9, 1.0, 1.0, 0.0)]
    with open_bag(write_bag(tmp_path / "far.bag", frames, odom, gt)) as reader:
        poses = [f.ground_truth for f in reader.frames()]
        assert reader.counters.frames_without_ground_truth == 1
    assert poses[0] == pytest.approx((0.0, 0.0, 0.0))  # held: 0.1 s after a pose
    assert poses[1] is None  # poses 5.9 s apart, none within 0.25 s
    assert poses[2] == pytest.approx((1.0, 1.0, 0.0))  # held: 0.1 s after the last pose


def test_bag_without_ground_truth(tmp_path: Path) -> None:
    with open_bag(simple_bag(tmp_path / "nogt.bag", gt=False)) as reader:
        assert not reader.info.has_ground_truth
        frames = list(reader.frames())
        assert reader.counters.frames_without_ground_truth == 0
    assert len(frames) == 10
    assert all(f.ground_truth is None for f in frames)


def test_ground_truth_can_be_ignored(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "ign.bag")
    with open_bag(path, topics=BagTopics(ground_truth=None)) as reader:
        assert not reader.info.has_ground_truth
        assert all(f.ground_truth is None for f in reader.frames())


@pytest.mark.parametrize("scale", [1, 2, 4, 8])
def test_reduced_decoding_sizes(tmp_path: Path, scale: int) -> None:
    with open_bag(simple_bag(tmp_path / "s.bag", n=2), image_scale=scale) as reader:
        frame = next(iter(reader.frames()))
    assert frame.image.shape == (240 // scale, 416 // scale)
    assert frame.image.dtype == np.uint8


def test_bad_image_scale_is_a_parameter_error(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="use 1, 2, 4 or 8"):
        open_bag(simple_bag(tmp_path / "s.bag", n=2), image_scale=3)


def test_start_time_skips_frames_but_keeps_odometry_and_index(tmp_path: Path) -> None:
    n = 40  # 8 s of data so that the start lies past the read-ahead margin
    path = simple_bag(tmp_path / "st.bag", n=n)
    with open_bag(path) as reader:
        full = list(reader.frames())
        late = list(reader.frames(start_time=5.0))
    assert late[0].time >= 5.0
    assert late[0].index == 0
    same = [f for f in full if f.time >= 5.0]
    assert len(late) == len(same)
    for a, b in zip(late, same, strict=True):
        assert a.time == b.time
        assert a.translation == pytest.approx(b.translation, abs=1e-12)
        assert a.rotation == pytest.approx(b.rotation, abs=1e-12)
        assert a.ground_truth == pytest.approx(b.ground_truth)
        np.testing.assert_array_equal(a.image, b.image)


def test_start_time_outside_the_bag(tmp_path: Path) -> None:
    with open_bag(simple_bag(tmp_path / "s.bag", n=3)) as reader:
        with pytest.raises(ParameterError, match="outside the bag"):
            reader.frames(start_time=100.0)


def test_one_pass_at_a_time(tmp_path: Path) -> None:
    with open_bag(simple_bag(tmp_path / "s.bag", n=3)) as reader:
        first = reader.frames()
        next(first)
        with pytest.raises(BagError, match="already being read"):
            reader.frames()
        first.close()
        assert len(list(reader.frames())) == 3


def test_overridden_topic_names(tmp_path: Path) -> None:
    topics = BagTopics(image="/cam/compressed", odometry="/odom", ground_truth="/truth")
    frames = [(0.1, jpeg(0)), (0.2, jpeg(1))]
    odom = [(0.0, 1.0, 0.0), (0.1, 1.0, 0.0), (0.2, 1.0, 0.0)]
    gt = [(0.0, 0.0, 0.0, 0.0), (0.3, 0.3, 0.0, 0.0)]
    path = write_bag(tmp_path / "named.bag", frames, odom, gt, topics=topics)
    with pytest.raises(BagTopicError):
        open_bag(path)
    with open_bag(path, topics=topics) as reader:
        got = list(reader.frames())
    assert [f.translation for f in got] == pytest.approx([0.1, 0.1])
    assert got[1].ground_truth == pytest.approx((0.2, 0.0, 0.0))


def test_ros1_bag_with_another_suffix(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "x.bag", n=3)
    other = path.rename(tmp_path / "recording.dat")
    with open_bag(other) as reader:
        assert len(list(reader.frames())) == 3


def test_ros2_bag(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types

    def header(ns: int) -> object:
        stamp = t["builtin_interfaces/msg/Time"](sec=ns // S, nanosec=ns % S)
        return t["std_msgs/msg/Header"](stamp=stamp, frame_id="x")

    vec = t["geometry_msgs/msg/Vector3"]
    zeros = np.zeros(36)
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    out = tmp_path / "ros2bag"
    with Writer(out, version=9) as writer:
        ci = writer.add_connection(
            "/irat_red/camera/image/compressed", "sensor_msgs/msg/CompressedImage", typestore=store
        )
        co = writer.add_connection("/irat_red/odom", "nav_msgs/msg/Odometry", typestore=store)
        cg = writer.add_connection("/overhead/pose", "geometry_msgs/msg/Pose2D", typestore=store)
        for k in range(4):
            ns = T0 + k * S // 10
            odom = t["nav_msgs/msg/Odometry"](
                header=header(ns),
                child_frame_id="b",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=zeros),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](
                        linear=vec(x=0.5, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.2)
                    ),
                    covariance=zeros,
                ),
            )
            writer.write(co, ns, store.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            p2d = t["geometry_msgs/msg/Pose2D"](x=float(k), y=0.0, theta=0.1)
            writer.write(cg, ns, store.serialize_cdr(p2d, "geometry_msgs/msg/Pose2D"))
            img = t["sensor_msgs/msg/CompressedImage"](
                header=header(ns + 1), format="jpeg", data=np.frombuffer(jpeg(k), np.uint8)
            )
            writer.write(ci, ns + 1, store.serialize_cdr(img, "sensor_msgs/msg/CompressedImage"))
    with open_bag(out) as reader:
        assert reader.info.ros_version == 2
        frames = list(reader.frames())
    assert len(frames) == 4
    assert [f.translation for f in frames] == pytest.approx([0.0, 0.05, 0.05, 0.05])
    assert [f.rotation for f in frames] == pytest.approx([0.0, 0.02, 0.02, 0.02])
    assert frames[2].ground_truth == pytest.approx((2.0, 0.0, 0.1), abs=1e-6)


# ------------------------------------------------------------------------------------ bad files
def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        open_bag(tmp_path / "nope.bag")


def test_empty_file(tmp_path: Path) -> None:
    (tmp_path / "e.bag").write_bytes(b"")
    with pytest.raises(BagError, match="is empty"):
        open_bag(tmp_path / "e.bag")


def test_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / "t.bag").write_text("hello\n")
    with pytest.raises(BagError, match="is not a ROS bag"):
        open_bag(tmp_path / "t.bag")


def test_folder_that_is_not_a_ros2_bag(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no metadata.yaml"):
        open_bag(tmp_path)


def test_truncated_bag(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "tr.bag")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"is truncated: its index starts at byte \d+ but"):
        open_bag(path)


def test_unindexed_bag(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "ui.bag")
    data = bytearray(path.read_bytes())
    pos = data.index(b"index_pos=") + len(b"index_pos=")
    data[pos : pos + 8] = bytes(8)
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match="has no index"):
        open_bag(path)


def test_corrupt_index(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "ci.bag")
    data = bytearray(path.read_bytes())
    pos = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = int.from_bytes(data[pos : pos + 8], "little")
    data[index_pos : index_pos + 64] = b"\xff" * 64
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match="cannot read bag .*damaged or truncated"):
        open_bag(path)


def test_corrupt_chunk_is_an_error_not_a_traceback(tmp_path: Path) -> None:
    path = simple_bag(tmp_path / "cc.bag", n=10)
    data = bytearray(path.read_bytes())
    # garbage over the middle half of the file: message records, not the index at the end
    a, b = len(data) // 4, 3 * len(data) // 4
    data[a:b] = b"\x07" * (b - a)
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"is corrupt near t=\d"):
        with open_bag(path) as reader:
            list(reader.frames())


def test_cli_reports_a_bad_bag_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = simple_bag(tmp_path / "tr.bag")
    path.write_bytes(path.read_bytes()[:5000])
    assert main(["dataset", "info", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert "truncated" in err


# ------------------------------------------------------------------------- topics and types
def test_missing_topic_lists_the_topics_present(tmp_path: Path) -> None:
    path = tmp_path / "mt.bag"
    with IratBagWriter(path) as bag:
        bag.write_image(T0, jpeg(0))
        bag.write_ground_truth(T0, 0.0, 0.0, 0.0)
    with pytest.raises(BagTopicError) as err:
        open_bag(path, odometry="wheel")  # (by default the camera's odometry stands in)
    message = str(err.value)
    assert "no odometry topic /irat_red/odom" in message
    assert "/irat_red/camera/image/compressed (sensor_msgs/msg/CompressedImage)" in message
    assert "/overhead/pose (geometry_msgs/msg/PoseStamped)" in message
    assert "\n" not in message


def test_wrong_message_type_on_camera_topic(tmp_path: Path) -> None:
    t = ros1_typestore().types
    path = tmp_path / "wt.bag"
    with IratBagWriter(path) as bag:
        raw = t["sensor_msgs/msg/Image"](
            header=bag.header("/irat_red/camera/image/compressed", T0, "c"),
            height=1,
            width=1,
            encoding="mono8",
            is_bigendian=0,
            step=1,
            data=np.zeros(1, np.uint8),
        )
        bag.write_message("/irat_red/camera/image/compressed", T0, raw)
        bag.write_odometry(T0, 0.0, 0.0)
    with pytest.raises(BagMessageTypeError, match="carries sensor_msgs/msg/Image, but the camera"):
        open_bag(path)


def test_wrong_message_type_on_ground_truth_topic(tmp_path: Path) -> None:
    t = ros1_typestore().types
    path = tmp_path / "wg.bag"
    with IratBagWriter(path) as bag:
        bag.write_image(T0, jpeg(0))
        bag.write_odometry(T0, 0.0, 0.0)
        bag.write_message("/overhead/pose", T0, t["std_msgs/msg/String"](data="x"))
    with open_bag(path) as reader:  # ground truth is optional: warn, read without it
        assert not reader.info.has_ground_truth
        assert reader.info.ground_truth_topic is None
        assert all(f.ground_truth is None for f in reader.frames())
        assert reader.warnings == [
            "ground-truth topic /overhead/pose carries std_msgs/msg/String, not a pose type "
            "(PoseStamped, Pose, Pose2D, PoseWithCovarianceStamped, Odometry); reading without "
            "ground truth"
        ]


@pytest.mark.parametrize(
    "msgtype",
    [
        "geometry_msgs/msg/Pose",
        "geometry_msgs/msg/Pose2D",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "nav_msgs/msg/Odometry",
    ],
)
def test_other_ground_truth_types(tmp_path: Path, msgtype: str) -> None:
    t = ros1_typestore().types
    path = tmp_path / "g.bag"
    yaw = 0.7
    quat = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.5, y=-2.0, z=0.0), orientation=quat
    )
    with IratBagWriter(path) as bag:
        for k in range(2):
            ns = T0 + k * S
            if msgtype == "geometry_msgs/msg/Pose":
                msg = pose
            elif msgtype == "geometry_msgs/msg/Pose2D":
                msg = t[msgtype](x=1.5, y=-2.0, theta=yaw)
            elif msgtype == "nav_msgs/msg/Odometry":
                msg = t[msgtype](
                    header=bag.header("/overhead/pose", ns, "o"),
                    child_frame_id="irat",
                    pose=t["geometry_msgs/msg/PoseWithCovariance"](
                        pose=pose, covariance=np.zeros(36)
                    ),
                    twist=t["geometry_msgs/msg/TwistWithCovariance"](
                        twist=t["geometry_msgs/msg/Twist"](
                            linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                            angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        ),
                        covariance=np.zeros(36),
                    ),
                )
            else:
                msg = t[msgtype](
                    header=bag.header("/overhead/pose", ns, "o"),
                    pose=t["geometry_msgs/msg/PoseWithCovariance"](
                        pose=pose, covariance=np.zeros(36)
                    ),
                )
            bag.write_message("/overhead/pose", ns, msg)
            bag.write_odometry(ns, 0.0, 0.0)
            bag.write_image(ns + S // 2, jpeg(k))
    with open_bag(path) as reader:
        assert reader.info.ground_truth_type == msgtype
        frame = next(iter(reader.frames()))
    assert frame.ground_truth == pytest.approx((1.5, -2.0, yaw))


# ----------------------------------------------------------------------- counted bad data
def test_undecodable_jpeg_is_skipped_and_counted_and_odometry_carries_over(
    tmp_path: Path,
) -> None:
    frames = [(0.1, jpeg(0)), (0.2, b"not a jpeg"), (0.3, b""), (0.4, jpeg(3))]
    odom = [(0.05 * k, 1.0, 0.5) for k in range(9)]
    with open_bag(write_bag(tmp_path / "uj.bag", frames, odom)) as reader:
        got = list(reader.frames())
        assert reader.counters.undecodable_images == 2
        assert reader.warnings == ["2 x undecodable camera image skipped (first at t=0.20 s)"]
    assert [f.index for f in got] == [0, 1]
    assert got[1].time == pytest.approx(0.4)
    assert got[1].translation == pytest.approx(0.3)  # 0.1 .. 0.4 s at 1 m/s
    assert got[1].rotation == pytest.approx(0.15)


def test_bag_with_no_decodable_image_is_an_error(tmp_path: Path) -> None:
    frames = [(0.1, b"junk"), (0.2, b"junk")]
    with open_bag(write_bag(tmp_path / "nd.bag", frames, [(0.0, 0.0, 0.0)])) as reader:
        with pytest.raises(BagError, match="none of the 2 camera images"):
            list(reader.frames())


def test_image_of_another_size_is_skipped(tmp_path: Path) -> None:
    frames = [(0.1, jpeg(0)), (0.2, jpeg(1, (120, 208))), (0.3, jpeg(2))]
    with open_bag(write_bag(tmp_path / "sz.bag", frames, [(0.0, 0.0, 0.0)])) as reader:
        got = list(reader.frames())
        assert reader.counters.image_size_changes == 1
    assert [f.time for f in got] == pytest.approx([0.1, 0.3])


def test_corrupt_message_is_skipped_and_counted(tmp_path: Path) -> None:
    path = tmp_path / "cm.bag"
    with IratBagWriter(path) as bag:
        bag.write_odometry(T0, 1.0, 0.0)
        bag.write_image(T0 + S // 10, jpeg(0))
        bag.write_raw("/irat_red/odom", "nav_msgs/msg/Odometry", T0 + S // 5, b"\x01\x02")
        bag.write_odometry(T0 + 3 * S // 10, 1.0, 0.0)
        bag.write_image(T0 + 4 * S // 10, jpeg(1))
    with open_bag(path) as reader:
        got = list(reader.frames())
        assert reader.counters.corrupt_messages == 1
    assert len(got) == 2
    assert got[1].translation == pytest.approx(0.3)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_odometry_is_skipped_and_counted(tmp_path: Path, bad: float) -> None:
    frames = [(0.35, jpeg(0))]
    odom = [(0.0, 1.0, 0.0), (0.1, 1.0, 0.0), (0.2, bad, 0.0), (0.3, 1.0, bad)]
    with open_bag(write_bag(tmp_path / "nf.bag", frames, odom)) as reader:
        (frame,) = list(reader.frames())
        assert reader.counters.nonfinite_odometry == 2
        assert "2 x odometry with NaN/inf velocity skipped (first at t=0.20 s)" in reader.warnings
    assert frame.translation == pytest.approx(0.1)  # only the 0.0 -> 0.1 interval is known
    assert math.isfinite(frame.rotation)


def test_odometry_stamps_backwards_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "ob.bag"
    with IratBagWriter(path) as bag:
        # record times increase, one header stamp is out of order (late delivery)
        for rec, stamp in [(0.0, 0.0), (0.1, 0.1), (0.2, 0.3), (0.3, 0.2), (0.4, 0.4)]:
            bag.write_odometry(T0 + round(stamp * S), 1.0, 0.0, record_ns=T0 + round(rec * S))
        bag.write_image(T0 + round(0.5 * S), jpeg(0))
    with open_bag(path) as reader:
        (frame,) = list(reader.frames())
        assert reader.counters.odometry_stamps_backwards == 1
        assert reader.counters.odometry_clock_resets == 0
    assert frame.translation == pytest.approx(0.4)  # 0 -> 0.1 -> 0.3 -> 0.4, the 0.2 dropped


def test_odometry_clock_reset_is_accepted_after_three(tmp_path: Path) -> None:
    path = tmp_path / "cr.bag"
    stamps = [10.0, 10.1, 10.2, 0.1, 0.2, 0.3, 0.4, 0.5]
    with IratBagWriter(path) as bag:
        for k, stamp in enumerate(stamps):
            bag.write_odometry(T0 + round(stamp * S), 1.0, 0.0, record_ns=T0 + k * S // 10)
        bag.write_image(T0 + round(0.55 * S), jpeg(0), record_ns=T0 + 8 * S // 10)
    with open_bag(path) as reader:
        frames = list(reader.frames())
        c = reader.counters
    assert c.odometry_stamps_backwards == 3
    assert c.odometry_clock_resets == 1
    # 10.0 -> 10.2 gives 0.2 m; after the reset at 0.3: 0.3 -> 0.5 gives 0.2 m
    assert sum(f.translation for f in frames) == pytest.approx(0.4)


def test_odometry_gap_contributes_nothing(tmp_path: Path) -> None:
    frames = [(5.0, jpeg(0))]
    odom = [(0.0, 1.0, 0.0), (0.1, 1.0, 0.0), (3.0, 1.0, 0.0), (3.1, 1.0, 0.0)]
    with open_bag(write_bag(tmp_path / "gap.bag", frames, odom)) as reader:
        (frame,) = list(reader.frames())
        assert reader.counters.odometry_gaps == 1
    assert frame.translation == pytest.approx(0.2)


def test_image_stamps_backwards_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "ib.bag"
    with IratBagWriter(path) as bag:
        bag.write_odometry(T0, 0.0, 0.0)
        for rec, stamp, k in [(0.1, 0.1, 0), (0.2, 0.3, 1), (0.3, 0.2, 2), (0.4, 0.4, 3)]:
            bag.write_image(T0 + round(stamp * S), jpeg(k), record_ns=T0 + round(rec * S))
    with open_bag(path) as reader:
        got = list(reader.frames())
        assert reader.counters.image_stamps_backwards == 1
    assert [f.time for f in got] == pytest.approx([0.1, 0.3, 0.4])


def test_ground_truth_nonfinite_and_backwards_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "gb.bag"
    with IratBagWriter(path) as bag:
        bag.write_odometry(T0, 0.0, 0.0)
        bag.write_ground_truth(T0, 0.0, 0.0, 0.0)
        bag.write_ground_truth(T0 + S // 10, math.nan, 0.0, 0.0)
        bag.write_ground_truth(T0 - S, 9.0, 9.0, 0.0, record_ns=T0 + S // 5)  # 1 s in the past
        bag.write_ground_truth(T0 + 4 * S // 10, 0.4, 0.0, 0.0)
        bag.write_image(T0 + 3 * S // 10, jpeg(0))
    with open_bag(path) as reader:
        (frame,) = list(reader.frames())
        c = reader.counters
    assert c.nonfinite_ground_truth == 1
    assert c.ground_truth_stamps_backwards == 1
    assert frame.ground_truth == pytest.approx((0.3, 0.0, 0.0))


def test_reading_streams_with_flat_memory(tmp_path: Path) -> None:
    import tracemalloc

    def peak_while_reading(n: int) -> tuple[int, int]:
        frames = [(0.1 + 0.05 * k, jpeg(k % 7)) for k in range(n)]
        odom = [(0.05 * k, 0.1, 0.0) for k in range(n + 2)]
        gt = [(0.1 * k, 0.0, 0.0, 0.0) for k in range(n // 2 + 2)]
        path = write_bag(tmp_path / f"m{n}.bag", frames, odom, gt)
        with open_bag(path) as reader:
            tracemalloc.start()
            count = sum(1 for _ in reader.frames())
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        return count, peak

    small_n, small_peak = peak_while_reading(100)
    big_n, big_peak = peak_while_reading(800)
    assert (small_n, big_n) == (100, 800)
    # eight times the frames (about 8 MB more JPEG data), not eight times the memory
    assert big_peak < 1.5 * small_peak + 1_000_000
