"""The ROS side of ``fleetbus ros replay``: a plain script for the ROS machine's own Python that
publishes recorded messages on a ROS master, as their original topics and types, on time.

It imports rospy and nothing of fleetbus (like ``ros_side.py``). JSON lines on stdin:
  ``advertise``  ``topic``, ``type`` (``pkg/Type``), ``md5sum``, ``definition``: a publisher
  ``start``      ``subscribers``, ``timeout``, ``delay``: wait until every topic has that many
                 subscribers (or the timeout), then ``delay`` seconds more for the subscribers to
                 be ready to read (as ``rosbag play --delay``)
  ``message``    ``topic``, ``at_ns`` (nanoseconds after the first message), ``data`` (base64 of
                 the ROS 1 serialised message): published when its time comes
and on stdout: ``ready`` (the node is up), or ``error`` (``error``: no master answered within
``MASTER_WAIT_S``, the script then ends), ``started`` (``subscribers``: per topic, when the clock
started), ``done`` (``published``: per topic) once the input ends and everything is published.
"""

from __future__ import annotations

import base64
import json
import signal
import sys
import time
from typing import Any

import genpy.dynamic
import rosgraph
import roslib.message
import rospy

#: How long a replay waits for the ROS master to answer before it gives up (rospy would wait for
#: ever, saying nothing the caller sees).
MASTER_WAIT_S = 10.0


def say(item: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(item) + "\n")
    sys.stdout.flush()


def message_class(type_name: str, md5sum: str, definition: str) -> type:
    """A class of the type (the installed one when it is the same version, else one made from the
    definition) whose messages are sent as the bytes they hold, as recorded: rospy would renumber
    a header's ``seq`` of a message it serialises itself."""
    cls = roslib.message.get_message_class(type_name)
    if cls is None or cls._md5sum != md5sum:
        cls = genpy.dynamic.generate_dynamic(type_name, definition)[type_name]

    class Recorded(cls):  # type: ignore[valid-type,misc]
        __slots__ = ("recorded",)

        def serialize(self, buff: Any) -> None:
            buff.write(self.recorded)

    Recorded._type, Recorded._md5sum, Recorded._full_text = cls._type, cls._md5sum, cls._full_text
    return Recorded


class Replay:
    def __init__(self) -> None:
        self.publishers: dict[str, tuple[rospy.Publisher, type]] = {}
        self.published: dict[str, int] = {}
        self.started: float | None = None

    def advertise(self, item: dict[str, Any]) -> None:
        cls = message_class(item["type"], item["md5sum"], item["definition"])
        # queue_size=None: publish() writes to the subscribers' sockets before it returns
        publisher = rospy.Publisher(item["topic"], cls, queue_size=None)  # type: ignore[arg-type]
        self.publishers[item["topic"]] = (publisher, cls)
        self.published[item["topic"]] = 0

    def start(self, item: dict[str, Any]) -> None:
        deadline = time.monotonic() + float(item.get("timeout", 30))
        wanted = int(item.get("subscribers", 0))
        while time.monotonic() < deadline and any(
            publisher.get_num_connections() < wanted for publisher, _ in self.publishers.values()
        ):
            time.sleep(0.02)  # rospy offers no wait for a subscriber
        counts = {topic: publisher.get_num_connections() for topic, (publisher, _) in self.publishers.items()}
        time.sleep(float(item.get("delay", 0.0)))  # what rosbag play gives new subscribers, too
        say({"kind": "started", "subscribers": counts})

    def message(self, item: dict[str, Any]) -> None:
        publisher, cls = self.publishers[item["topic"]]
        message = cls()
        message.recorded = base64.b64decode(item["data"])
        if self.started is None:
            self.started = time.monotonic()  # the clock starts with the first message
        due = self.started + item["at_ns"] / 1e9
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)  # the recorded pace: a schedule, not a wait for a condition
        publisher.publish(message)
        self.published[item["topic"]] += 1


def master_answers(deadline_s: float) -> bool:
    """Whether the master of ``ROS_MASTER_URI`` answers within ``deadline_s`` (asked every 0.2 s)."""
    master = rosgraph.Master("/fleetbus_replay")
    deadline = time.monotonic() + deadline_s
    while True:
        try:
            master.getPid()
            return True
        except OSError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.2)  # polling the master, as rospy itself does while it waits


def main() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches fleetbus, which closes our input
    if not master_answers(MASTER_WAIT_S):
        uri = rosgraph.get_master_uri()
        say({"kind": "error", "error": f"no ROS master answers at {uri} within {MASTER_WAIT_S:.0f} s"})
        sys.exit(3)
    rospy.init_node("fleetbus_replay", anonymous=True, disable_signals=True)
    replay = Replay()
    say({"kind": "ready"})
    actions = {"advertise": replay.advertise, "start": replay.start, "message": replay.message}
    for line in sys.stdin:
        item = json.loads(line)
        actions[item["kind"]](item)
    say({"kind": "done", "published": replay.published})
    rospy.signal_shutdown("replayed")


if __name__ == "__main__":
    main()
