"""Writes a ROS 1 bag of the sensor types Foxglove's panels draw, with ROS's own rosbag API and
message classes; run with the ROS machine's Python (/usr/bin/python3).

    sensor_bag.py PATH OFFSET [N]
                                an Image (4x3 rgb8), a PointCloud2 (3 points x, y, z), a LaserScan
                                (5 ranges, one inf), an OccupancyGrid (4x3) on /map, a TFMessage
                                (map->odom, odom->base_link) and a String on /chatter, each N times
                                (default 2), 100 ms apart; values shifted by OFFSET (so that two
                                bags differ)

Prints, as one JSON line, what it wrote: per topic, the type and each message's bytes (base64)
as rosbag serialised them.
"""

from __future__ import annotations

import base64
import io
import json
import struct
import sys

import rosbag
import rospy
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import Image, LaserScan, PointCloud2, PointField
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

T0 = 1_772_442_000


def messages(offset: int, i: int, stamp: rospy.Time) -> list[tuple[str, object]]:
    image = Image(height=3, width=4, encoding="rgb8", is_bigendian=0, step=12)
    image.header.stamp, image.header.frame_id = stamp, "camera"
    image.data = bytes((offset + i + k) % 256 for k in range(36))
    cloud = PointCloud2(height=1, width=3, is_bigendian=False, point_step=12, row_step=36, is_dense=True)
    cloud.header.stamp, cloud.header.frame_id = stamp, "lidar"
    cloud.fields = [
        PointField(name=n, offset=4 * k, datatype=PointField.FLOAT32, count=1) for k, n in enumerate("xyz")
    ]
    cloud.data = b"".join(struct.pack("<fff", offset + p, i, -p) for p in range(3))
    scan = LaserScan(angle_min=-0.5, angle_max=0.5, angle_increment=0.25, range_min=0.1, range_max=10.0)
    scan.header.stamp, scan.header.frame_id = stamp, "laser"
    scan.ranges = [1.0 + offset, 2.0, float("inf"), 3.5, 0.5 + i]
    grid = OccupancyGrid()
    grid.header.stamp, grid.header.frame_id = stamp, "map"
    grid.info.resolution, grid.info.width, grid.info.height = 0.05, 4, 3
    grid.info.origin.orientation.w = 1.0
    grid.data = [0, 100, -1, 50, 0, 0, 100, offset % 100, 0, -1, 0, 100]
    transforms = []
    for parent, child, x in (("map", "odom", float(offset)), ("odom", "base_link", 1.5 * i)):
        moved = TransformStamped()
        moved.header.stamp, moved.header.frame_id, moved.child_frame_id = stamp, parent, child
        moved.transform.translation.x, moved.transform.rotation.w = x, 1.0
        transforms.append(moved)
    return [
        ("/camera/image_raw", image),
        ("/points", cloud),
        ("/scan", scan),
        ("/map", grid),
        ("/tf", TFMessage(transforms)),
        ("/chatter", String(data=f"hello {offset} {i}")),
    ]


def main() -> None:
    path, offset = sys.argv[1], int(sys.argv[2])
    count = int(sys.argv[3]) if len(sys.argv) > 3 else 2
    written: dict[str, dict[str, object]] = {}
    with rosbag.Bag(path, "w") as bag:
        for i in range(count):
            stamp = rospy.Time(T0 + offset, i * 100_000_000 + 123)
            for topic, message in messages(offset, i, stamp):
                bag.write(topic, message, stamp)
                buffer = io.BytesIO()
                message.serialize(buffer)
                entry = written.setdefault(topic, {"type": message._type, "data": []})
                entry["data"].append(base64.b64encode(buffer.getvalue()).decode())  # type: ignore[attr-defined]
    print(json.dumps(written))


if __name__ == "__main__":
    main()
