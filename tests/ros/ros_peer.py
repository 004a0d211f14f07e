"""A ROS node for the bridge's tests, run with the ROS machine's Python (/usr/bin/python3).

    ros_peer.py samples            latched samples: /chatter (std_msgs/String), /robot_pose
                                   (geometry_msgs/PoseStamped), /map (nav_msgs/OccupancyGrid),
                                   /imu (sensor_msgs/Imu, a type fleetbus has no model of), and on
                                   topics no rule maps /move_base_simple/goal (a PoseStamped at
                                   x=42, y=-7) and /move_base/local_costmap/costmap (a grid)
    ros_peer.py burst TOPIC N      N std_msgs/String on TOPIC ("0".."N-1") once someone subscribed,
                                   then "last" (the sentinel)
    ros_peer.py listen TOPIC TYPE  print each message received on TOPIC as a JSON line
    ros_peer.py record TOPIC...    print each message received on the TOPICs, of whatever type, as a
                                   JSON line: topic, type, its bytes (base64), when (monotonic s)
    ros_peer.py scene N            once each topic has N subscribers: /chatter "hello 0".."hello 4"
                                   then "goodbye"; /tf three tf2_msgs/TFMessage of two transforms
                                   (map->odom x=i, odom->base_link x=10+i); /odom three
                                   nav_msgs/Odometry (pose x=i, twist linear x=0.5*i); "sent" after
    ros_peer.py sensors N HZ       once each topic has a subscriber: N 640x480 rgb8 sensor_msgs/Image
                                   on /camera/image_raw and N sensor_msgs/PointCloud2 of 65,536
                                   points (1 MiB) on /points, at HZ, then one 1280x720 image on
                                   /camera/huge; then one line {"sent": [...]}: each message's
                                   topic, seq, and its data's length and SHA-256

Prints "ready" once its publishers or subscriber exist; runs until its standard input closes.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import sys
import threading
import time
from typing import Any

import roslib.message
import rospy
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from sensor_msgs.msg import Image, Imu, PointCloud2, PointField
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

STAMP = rospy.Time(1_700_000_000, 250_000_000)


def say(item: object) -> None:
    sys.stdout.write(json.dumps(item) + "\n")
    sys.stdout.flush()


def samples() -> list[rospy.Publisher]:
    chatter = rospy.Publisher("/chatter", String, queue_size=10, latch=True)
    chatter.publish(String(data="hello fleetbus"))
    pose = PoseStamped()
    pose.header.stamp, pose.header.frame_id = STAMP, "map"
    pose.pose.position.x, pose.pose.position.y = 3.5, -1.25
    pose.pose.orientation.z, pose.pose.orientation.w = 0.0, 1.0
    poses = rospy.Publisher("/robot_pose", PoseStamped, queue_size=10, latch=True)
    poses.publish(pose)
    grid = OccupancyGrid()
    grid.header.stamp, grid.header.frame_id = STAMP, "map"
    grid.info.resolution, grid.info.width, grid.info.height = 0.05, 4, 3
    grid.info.origin.position.x, grid.info.origin.position.y = -1.0, -2.0
    grid.info.origin.orientation.w = 1.0
    grid.data = [0, 0, 100, -1, 0, 50, 100, 0, 0, 0, 0, 100]
    maps = rospy.Publisher("/map", OccupancyGrid, queue_size=1, latch=True)
    maps.publish(grid)
    imu = Imu()
    imu.header.stamp, imu.header.frame_id = STAMP, "imu_link"
    imu.linear_acceleration.z = 9.81
    imu.orientation_covariance = [0.5] * 9
    imus = rospy.Publisher("/imu", Imu, queue_size=10, latch=True)
    imus.publish(imu)
    # a pose and a grid on topics no rule names: an operator's goal, a local costmap
    goal = PoseStamped()
    goal.header.stamp, goal.header.frame_id = STAMP, "map"
    goal.pose.position.x, goal.pose.position.y, goal.pose.orientation.w = 42.0, -7.0, 1.0
    goals = rospy.Publisher("/move_base_simple/goal", PoseStamped, queue_size=1, latch=True)
    goals.publish(goal)
    costmaps = rospy.Publisher("/move_base/local_costmap/costmap", OccupancyGrid, queue_size=1, latch=True)
    costmaps.publish(grid)
    return [chatter, poses, maps, imus, goals, costmaps]


def burst(topic: str, count: int) -> rospy.Publisher:
    publisher = rospy.Publisher(topic, String, queue_size=count + 10)

    def run() -> None:
        while publisher.get_num_connections() == 0 and not rospy.is_shutdown():
            time.sleep(0.01)
        for i in range(count):
            publisher.publish(String(data=str(i)))
        publisher.publish(String(data="last"))

    threading.Thread(target=run, daemon=True).start()
    return publisher


def transform(parent: str, child: str, x: float, stamp: rospy.Time) -> TransformStamped:
    moved = TransformStamped()
    moved.header.stamp, moved.header.frame_id, moved.child_frame_id = stamp, parent, child
    moved.transform.translation.x = x
    moved.transform.rotation.w = 1.0
    return moved


def scene(subscribers: int) -> list[rospy.Publisher]:
    chatter = rospy.Publisher("/chatter", String, queue_size=100)
    tf = rospy.Publisher("/tf", TFMessage, queue_size=100)
    odom = rospy.Publisher("/odom", Odometry, queue_size=100)
    publishers = [chatter, tf, odom]

    def run() -> None:
        while any(p.get_num_connections() < subscribers for p in publishers) and not rospy.is_shutdown():
            time.sleep(0.01)
        for i in range(5):
            chatter.publish(String(data=f"hello {i}"))
        for i in range(3):
            stamp = rospy.Time(STAMP.secs + i, 0)
            pair = [transform("map", "odom", i, stamp), transform("odom", "base_link", 10.0 + i, stamp)]
            tf.publish(TFMessage(pair))
            moved = Odometry()
            moved.header.stamp, moved.header.frame_id, moved.child_frame_id = stamp, "odom", "base_link"
            moved.pose.pose.position.x, moved.pose.pose.orientation.w = float(i), 1.0
            moved.twist.twist.linear.x = 0.5 * i
            odom.publish(moved)
            time.sleep(0.05)  # three distinct log times, for a time window
        chatter.publish(String(data="goodbye"))
        say("sent")

    threading.Thread(target=run, daemon=True).start()
    return publishers


def image(seq: int, width: int, height: int) -> Image:
    frame = Image(height=height, width=width, encoding="rgb8", is_bigendian=0, step=width * 3)
    frame.header.seq, frame.header.stamp, frame.header.frame_id = seq, STAMP, "camera"
    frame.data = os.urandom(width * height * 3)
    return frame


def cloud(seq: int, points: int) -> PointCloud2:
    fields = [PointField(name, 4 * i, PointField.FLOAT32, 1) for i, name in enumerate("xyz")]
    fields.append(PointField("rgb", 12, PointField.FLOAT32, 1))
    made = PointCloud2(height=1, width=points, fields=fields, is_bigendian=False, point_step=16)
    made.header.seq, made.header.stamp, made.header.frame_id = seq, STAMP, "lidar"
    made.row_step, made.is_dense = 16 * points, True
    made.data = os.urandom(16 * points)
    return made


def sensors(count: int, hz: float) -> list[rospy.Publisher]:
    images = rospy.Publisher("/camera/image_raw", Image, queue_size=count + 1)
    points = rospy.Publisher("/points", PointCloud2, queue_size=count + 1)
    huge = rospy.Publisher("/camera/huge", Image, queue_size=1)
    publishers = [images, points, huge]

    said: list[dict[str, object]] = []

    def sent(topic: str, seq: int, data: bytes) -> None:
        digest = hashlib.sha256(data).hexdigest()
        said.append({"topic": topic, "seq": seq, "length": len(data), "sha256": digest})

    def run() -> None:
        while any(p.get_num_connections() < 1 for p in publishers) and not rospy.is_shutdown():
            time.sleep(0.01)
        for seq in range(count):
            frame, made = image(seq, 640, 480), cloud(seq, 65_536)
            images.publish(frame)
            sent("/camera/image_raw", seq, frame.data)
            points.publish(made)
            sent("/points", seq, made.data)
            time.sleep(1.0 / hz)
        frame = image(0, 1280, 720)
        huge.publish(frame)
        sent("/camera/huge", 0, frame.data)
        say({"sent": said})

    threading.Thread(target=run, daemon=True).start()
    return publishers


def listen(topic: str, type_name: str) -> rospy.Subscriber:
    cls = roslib.message.get_message_class(type_name)

    def received(msg: Any) -> None:
        if hasattr(msg, "data"):
            say({"topic": topic, "data": msg.data})
        else:
            position = msg.pose.position
            say({"topic": topic, "frame_id": msg.header.frame_id, "x": position.x, "y": position.y})

    return rospy.Subscriber(topic, cls, received)


def record(topics: list[str]) -> list[rospy.Subscriber]:
    def received(raw: rospy.AnyMsg, topic: str) -> None:
        kind = raw._connection_header["type"]
        data = base64.b64encode(raw._buff).decode()
        say({"topic": topic, "type": kind, "data": data, "t": time.monotonic()})

    return [rospy.Subscriber(topic, rospy.AnyMsg, received, callback_args=topic) for topic in topics]


def main() -> None:
    rospy.init_node("fleetbus_test_peer", anonymous=True, disable_signals=True)
    mode, args = sys.argv[1], sys.argv[2:]
    modes = {
        "samples": lambda: samples(),
        "burst": lambda: burst(args[0], int(args[1])),
        "listen": lambda: listen(*args),
        "scene": lambda: scene(int(args[0])),
        "record": lambda: record(args),
        "sensors": lambda: sensors(int(args[0]), float(args[1])),
    }
    keep = modes[mode]()
    say("ready")
    sys.stdin.read()  # until the test closes our input
    del keep
    rospy.signal_shutdown("done")


if __name__ == "__main__":
    main()
