"""The ROS node of ``bench.ros_bridge``, for the ROS machine's Python (/usr/bin/python3).

    publisher.py SECONDS SMALL_HZ IMAGE_HZ SUBSCRIBERS [SMALL_BYTES]

Once each topic has SUBSCRIBERS subscribers, publishes for SECONDS: std_msgs/String on /bench/small
at SMALL_HZ (its text SMALL_BYTES long, default about 20), and a 640x480 rgb8 sensor_msgs/Image on
/bench/image at IMAGE_HZ (0: none), on a fixed schedule (late sends are sent at once, not
skipped). Prints the counts sent as one JSON line.
"""

from __future__ import annotations

import json
import sys
import time

import rospy
from sensor_msgs.msg import Image
from std_msgs.msg import String


def main() -> None:
    seconds, small_hz, image_hz, subscribers = (
        float(sys.argv[1]),
        float(sys.argv[2]),
        float(sys.argv[3]),
        int(sys.argv[4]),
    )
    small_bytes = int(sys.argv[5]) if len(sys.argv) > 5 else 0
    rospy.init_node("bench_publisher", anonymous=True, disable_signals=True)
    small = rospy.Publisher("/bench/small", String, queue_size=10_000)
    image = rospy.Publisher("/bench/image", Image, queue_size=100)
    while min(small.get_num_connections(), image.get_num_connections()) < subscribers:
        time.sleep(0.05)
    frame = Image(height=480, width=640, encoding="rgb8", step=640 * 3, data=bytes(640 * 480 * 3))
    sent = {"/bench/small": 0, "/bench/image": 0}
    start = time.monotonic()
    next_small = next_image = start
    print(json.dumps({"started": time.time()}), flush=True)
    while (now := time.monotonic()) < start + seconds:
        if now >= next_small:
            text = f"small message {sent['/bench/small']}"
            small.publish(String(data=text.ljust(small_bytes, ".")))
            sent["/bench/small"] += 1
            next_small += 1 / small_hz
        if image_hz and now >= next_image:
            frame.header.stamp = rospy.Time.now()
            image.publish(frame)
            sent["/bench/image"] += 1
            next_image += 1 / image_hz
        due = min(next_small, next_image) if image_hz else next_small
        time.sleep(max(0.0, due - time.monotonic()))
    print(json.dumps({"sent": sent, "seconds": time.monotonic() - start}), flush=True)
    time.sleep(1.0)  # let the last messages leave the publisher's queues before the node goes
    rospy.signal_shutdown("done")


if __name__ == "__main__":
    main()
