"""ROS bags written in the tests with ``rosbags``' own writers (no ROS needed)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

#: The formats a test bag can be written in.
FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap")
START_NS = 1_764_000_000_123_456_789
"""The first message's log time: nanoseconds that a datetime cannot hold, on purpose."""


@dataclass(frozen=True)
class Written:
    topic: str
    ros_type: str
    log_time_ns: int
    fields: dict[str, Any]
    """What the message's fields are expected to read as."""


def write_bag(
    path: Path, kind: str, count: int = 30, image_bytes: int = 12, start_ns: int = START_NS
) -> list[Written]:
    """A bag of ``count`` messages on three topics (strings, odometry-like poses, images), in
    log-time order; returns what was written."""
    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = store.types
    string_t, pose_t, image_t = (
        "std_msgs/msg/String",
        "geometry_msgs/msg/PoseStamped",
        "sensor_msgs/msg/Image",
    )
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    writer: Any
    if ros1:
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if kind == "ros2-mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    written: list[Written] = []
    with writer:
        connections = {
            name: writer.add_connection(topic, name, typestore=store)
            for name, topic in (
                (string_t, "/chatter"),
                (pose_t, "/robot/pose"),
                (image_t, "/camera/image_raw"),
            )
        }
        for i in range(count):
            at = start_ns + i * 10_000_017
            stamp = types["builtin_interfaces/msg/Time"](sec=at // 10**9 - 1, nanosec=(at % 10**9))
            header_fields = {"seq": i} if ros1 else {}
            header = types["std_msgs/msg/Header"](**header_fields, stamp=stamp, frame_id="map")
            header_json = {
                **header_fields,
                "stamp": {"sec": stamp.sec, "nanosec": stamp.nanosec},
                "frame_id": "map",
            }
            kind_of = i % 3
            if kind_of == 0:
                name, message = string_t, types[string_t](data=f"hello {i}")
                expected: dict[str, Any] = {"data": f"hello {i}"}
            elif kind_of == 1:
                point = types["geometry_msgs/msg/Point"](x=float(i), y=2.5, z=0.0)
                quaternion = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
                pose = types["geometry_msgs/msg/Pose"](position=point, orientation=quaternion)
                name, message = pose_t, types[pose_t](header=header, pose=pose)
                expected = {
                    "header": header_json,
                    "pose": {
                        "position": {"x": float(i), "y": 2.5, "z": 0.0},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    },
                }
            else:
                pixels = np.frombuffer(bytes((i + k) % 256 for k in range(image_bytes)), dtype=np.uint8)
                name = image_t
                message = types[image_t](
                    header=header,
                    height=1,
                    width=image_bytes,
                    encoding="mono8",
                    is_bigendian=0,
                    step=image_bytes,
                    data=pixels,
                )
                expected = {
                    "header": header_json,
                    "height": 1,
                    "width": image_bytes,
                    "data": pixels.tobytes(),
                }
            connection = connections[name]
            writer.write(connection, at, serialize(message, name))
            written.append(Written(connection.topic, name, at, expected))
    return written


def storage_file(path: Path) -> Path:
    """The file holding a bag's messages (a ROS 2 bag's storage file, in its directory)."""
    if path.is_file():
        return path
    [file] = [p for p in path.iterdir() if p.suffix in (".db3", ".mcap")]
    return file
