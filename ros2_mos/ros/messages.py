"""Building the node's output messages for either rclpy or rosbags.

The node publishes rclpy messages; the offline ``process`` command writes the
same messages to a bag as rosbags dataclasses. Both accept every field as a
keyword argument, so one set of builders serves both through a
:class:`MessageTypes` namespace; only how byte payloads are stored differs
(rclpy: bytes, rosbags: a uint8 ndarray). Nothing here imports rclpy itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ros2_mos.io.pointcloud2 import CloudView, fill_subset, fill_with_extra_fields

#: Names of the fields /mos/labels adds to the input's fields.
LABEL_FIELD = "moving"
PROBABILITY_FIELD = "moving_probability"


@dataclass(frozen=True)
class MessageTypes:
    """The message classes of one backend; ``tf_message`` is None where tf2_msgs is missing."""

    time: Any
    header: Any
    point_cloud2: Any
    point_field: Any
    image: Any
    odometry: Any
    pose_with_covariance: Any
    twist_with_covariance: Any
    pose: Any
    twist: Any
    point: Any
    quaternion: Any
    vector3: Any
    transform: Any
    transform_stamped: Any
    tf_message: Any | None
    diagnostic_array: Any
    diagnostic_status: Any
    key_value: Any
    bytes_payload: Callable[[np.ndarray], Any]
    byte_value: Callable[[int], Any]  # a ROS `byte` field: bytes of length 1 in rclpy, int in rosbags

    @classmethod
    def rclpy(cls) -> MessageTypes:
        """rclpy's generated message classes (from the PyPI wheels or a ROS install)."""
        from builtin_interfaces.msg import Time
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from geometry_msgs.msg import (
            Point,
            Pose,
            PoseWithCovariance,
            Quaternion,
            Transform,
            TransformStamped,
            Twist,
            TwistWithCovariance,
            Vector3,
        )
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Image, PointCloud2, PointField
        from std_msgs.msg import Header

        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:  # not in the PyPI wheels; present on a ROS install
            TFMessage = None
        return cls(Time, Header, PointCloud2, PointField, Image, Odometry, PoseWithCovariance,
                   TwistWithCovariance, Pose, Twist, Point, Quaternion, Vector3, Transform, TransformStamped,
                   TFMessage, DiagnosticArray, DiagnosticStatus, KeyValue,
                   bytes_payload=lambda a: np.ascontiguousarray(a).tobytes(), byte_value=lambda v: bytes([v]))

    @classmethod
    def rosbags(cls) -> MessageTypes:
        """rosbags' Jazzy dataclasses, for writing bags."""
        from ros2_mos.io.bags import msg_class

        def t(name: str) -> Any:
            return msg_class(name)

        return cls(t("builtin_interfaces/msg/Time"), t("std_msgs/msg/Header"), t("sensor_msgs/msg/PointCloud2"),
                   t("sensor_msgs/msg/PointField"), t("sensor_msgs/msg/Image"), t("nav_msgs/msg/Odometry"),
                   t("geometry_msgs/msg/PoseWithCovariance"), t("geometry_msgs/msg/TwistWithCovariance"),
                   t("geometry_msgs/msg/Pose"), t("geometry_msgs/msg/Twist"), t("geometry_msgs/msg/Point"),
                   t("geometry_msgs/msg/Quaternion"), t("geometry_msgs/msg/Vector3"),
                   t("geometry_msgs/msg/Transform"), t("geometry_msgs/msg/TransformStamped"),
                   t("tf2_msgs/msg/TFMessage"), t("diagnostic_msgs/msg/DiagnosticArray"),
                   t("diagnostic_msgs/msg/DiagnosticStatus"), t("diagnostic_msgs/msg/KeyValue"),
                   bytes_payload=lambda a: np.ascontiguousarray(a).reshape(-1).view(np.uint8),
                   byte_value=int)


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds (exact, unlike float seconds)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def make_header(types: MessageTypes, stamp: int, frame_id: str) -> Any:
    """A Header for a stamp in integer nanoseconds."""
    sec, nanosec = divmod(int(stamp), 1_000_000_000)
    return types.header(stamp=types.time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def empty_cloud(types: MessageTypes, header: Any) -> Any:
    return types.point_cloud2(header=header, height=1, width=0, fields=[], is_bigendian=False, point_step=0,
                              row_step=0, data=types.bytes_payload(np.zeros(0, np.uint8)), is_dense=True)


def subset_cloud(types: MessageTypes, header: Any, view: CloudView, index: np.ndarray) -> Any:
    """The selected input points with all their fields (/mos/static_points, /mos/moving_points)."""
    return fill_subset(empty_cloud(types, header), view, index, field_factory=types.point_field)


def labels_cloud(types: MessageTypes, header: Any, view: CloudView, index: np.ndarray, labels: np.ndarray,
                 probability: np.ndarray) -> Any:
    """The selected input points plus ``moving`` (uint8 0/1) and ``moving_probability`` (float32)."""
    return fill_with_extra_fields(
        empty_cloud(types, header), view, index,
        [(LABEL_FIELD, np.asarray(labels, np.uint8)), (PROBABILITY_FIELD, np.asarray(probability, np.float32))],
        field_factory=types.point_field,
    )


def image_msg(types: MessageTypes, header: Any, image: np.ndarray) -> Any:
    """sensor_msgs/Image of a (H, W) float32 (encoding 32FC1) or uint8 (mono8) array."""
    arr = np.ascontiguousarray(image)
    if arr.dtype == np.float32:
        encoding = "32FC1"
    elif arr.dtype == np.uint8:
        encoding = "mono8"
    else:
        raise TypeError(f"image must be float32 or uint8, got {arr.dtype}")
    arr = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    height, width = arr.shape
    return types.image(header=header, height=height, width=width, encoding=encoding, is_bigendian=False,
                       step=width * arr.itemsize, data=types.bytes_payload(arr))


def rotation_to_quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3x3 rotation matrix (Shepperd's method: stable for every rotation)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = np.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    i = int(np.argmax(candidates))
    if i == 0:
        s = 2.0 * np.sqrt(max(1.0 + trace, 1e-12))
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif i == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-12))
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif i == 2:
        s = 2.0 * np.sqrt(max(1.0 - m[0, 0] + m[1, 1] - m[2, 2], 1e-12))
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * np.sqrt(max(1.0 - m[0, 0] - m[1, 1] + m[2, 2], 1e-12))
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    quat = np.array(q)
    quat /= np.linalg.norm(quat)
    if quat[3] < 0:
        quat = -quat
    return float(quat[0]), float(quat[1]), float(quat[2]), float(quat[3])


def odometry_msg(types: MessageTypes, header: Any, child_frame_id: str, pose: np.ndarray) -> Any:
    """nav_msgs/Odometry of a 4x4 world pose (no twist or covariance: KISS-ICP gives neither)."""
    p = np.asarray(pose, dtype=np.float64)
    x, y, z, w = rotation_to_quaternion(p[:3, :3])
    zero = types.vector3(x=0.0, y=0.0, z=0.0)
    return types.odometry(
        header=header,
        child_frame_id=child_frame_id,
        pose=types.pose_with_covariance(
            pose=types.pose(position=types.point(x=float(p[0, 3]), y=float(p[1, 3]), z=float(p[2, 3])),
                            orientation=types.quaternion(x=x, y=y, z=z, w=w)),
            covariance=np.zeros(36, dtype=np.float64)),
        twist=types.twist_with_covariance(twist=types.twist(linear=zero, angular=zero),
                                          covariance=np.zeros(36, dtype=np.float64)),
    )


def tf_msg(types: MessageTypes, header: Any, child_frame_id: str, pose: np.ndarray) -> Any | None:
    """tf2_msgs/TFMessage with the header.frame_id -> child transform; None where tf2_msgs is missing."""
    if types.tf_message is None:
        return None
    p = np.asarray(pose, dtype=np.float64)
    x, y, z, w = rotation_to_quaternion(p[:3, :3])
    transform = types.transform_stamped(
        header=header, child_frame_id=child_frame_id,
        transform=types.transform(translation=types.vector3(x=float(p[0, 3]), y=float(p[1, 3]), z=float(p[2, 3])),
                                  rotation=types.quaternion(x=x, y=y, z=z, w=w)))
    return types.tf_message(transforms=[transform])


# diagnostic_msgs/DiagnosticStatus levels (bytes in rclpy, ints in rosbags: both take these).
OK, WARN, ERROR, STALE = 0, 1, 2, 3


def diagnostics_msg(types: MessageTypes, header: Any, name: str, hardware_id: str, level: int, message: str,
                    values: Mapping[str, Any]) -> Any:
    """diagnostic_msgs/DiagnosticArray with one status carrying ``values`` as key/value strings."""
    status = types.diagnostic_status(
        level=types.byte_value(level), name=name, message=message, hardware_id=hardware_id,
        values=[types.key_value(key=str(k), value=_format(v)) for k, v in values.items()])
    return types.diagnostic_array(header=header, status=[status])


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def copy_cloud(types: MessageTypes, msg: Any) -> Any:
    """A PointCloud2 of ``types`` with the same header, layout and bytes as ``msg`` (of any backend).

    Used to publish bag messages (rosbags) with rclpy in ``replay``.
    """
    header = make_header(types, stamp_ns(msg.header.stamp), str(msg.header.frame_id))
    fields = [types.point_field(name=f.name, offset=int(f.offset), datatype=int(f.datatype), count=int(f.count))
              for f in msg.fields]
    data = msg.data if isinstance(msg.data, np.ndarray) else np.frombuffer(msg.data, dtype=np.uint8)
    return types.point_cloud2(header=header, height=int(msg.height), width=int(msg.width), fields=fields,
                              is_bigendian=bool(msg.is_bigendian), point_step=int(msg.point_step),
                              row_step=int(msg.row_step), data=types.bytes_payload(data),
                              is_dense=bool(msg.is_dense))
