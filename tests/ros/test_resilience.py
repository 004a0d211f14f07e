"""A bridge that keeps working: a master that starts after it, a master restarted under it, a ROS
side killed under it or whose node is shut down from outside, and a ROS side that never outlives
it; every failure retried and shown in ``fleetbus ros status``."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import re
import signal
import stat
import subprocess
import sys
import xmlrpc.client
from pathlib import Path
from typing import Any

import pika

from fleetbus.broker.accounts import Role
from fleetbus.broker.mounts import bind_all, mount_bindings
from fleetbus.publishers.ros.bridge import ROS_LOG_TOPIC, ROS_SIDE
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RobotKind
from tests.ros.conftest import ROS_PYTHON, RosMaster, ros_peer, running_bridge
from tests.support import Bus, read_line, wait_for
from tests.test_cli import fleetbus

BURST = 50
TOPICS = ("/before", "/after", "/again")


def burst_recorded(bridge: object, master: RosMaster, topic: str) -> None:
    """A ROS node sends BURST messages and a last one on ``topic`` once the bridge subscribed:
    the bridge records every one of them."""
    with ros_peer(master, "burst", topic, str(BURST)):
        wait_for(
            lambda: bridge.counters.recorded[topic] == BURST + 1,  # type: ignore[attr-defined]
            60,
            f"all of {topic} recorded",
        )


def send_command(operator_url: str, body: dict[str, object]) -> None:
    """The operator who mounted rosres1 sends it a command (the bridge latches it on /fleetbus/command)."""
    connection = blocking_connection(operator_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        properties = pika.BasicProperties(user_id="operres1")
        data = json.dumps(body).encode()
        channel.basic_publish("operres1.commands", "rosres1.say", data, properties, mandatory=True)
    finally:
        connection.close()


def latched_command(master: RosMaster) -> object:
    """What a ROS node that subscribes now gets on /fleetbus/command: the latched command's body."""
    with ros_peer(master, "listen", "/fleetbus/command", "std_msgs/String") as listener:
        line = json.loads(read_line(listener, '{"topic": "/fleetbus/command"', 30))
    return json.loads(line["data"])["body"]


def test_a_late_master_and_a_restarted_master_lose_nothing(bus: Bus, ros_master: RosMaster) -> None:
    account = bus.add("rosres1", kind=RobotKind.EXPLORER)
    robot = bus.robot(account)
    operator = bus.add("operres1", Role.OPERATOR)
    bind_all(bus.api, bus.vhost, mount_bindings("rosres1", "operres1"))  # what a mount does
    ros_master.stop()  # the bridge starts first
    with running_bridge(
        robot,
        ros_master,
        bus.settings.robots_dir,
        commands_url=account.amqp_url,
        node_up=False,
        retry_most_s=1.0,
        include=TOPICS,
    ) as bridge:
        master = wait_for(
            lambda: (m := bridge.counters.master)["state"] == "unreachable" and m["failures"] >= 2 and m,
            30,
            "the bridge trying the absent master again",
        )
        assert "ConnectionRefusedError" in master["detail"] and 0 < master["retry_in"] <= 1.0
        status = fleetbus(bus, "ros", "status", "rosres1")
        assert status.returncode == 0, status.stderr
        shown = json.loads(status.stdout)
        assert shown["master"]["state"] == "unreachable" and shown["ros_side"] == "waiting for the master"

        ros_master.start()
        wait_for(lambda: bridge.counters.ros_side == "running", 30, "the node up once the master is")
        burst_recorded(bridge, ros_master, "/before")
        send_command(operator.amqp_url, {"state": "first"})
        assert latched_command(ros_master) == {"state": "first"}

        ros_master.stop()
        wait_for(lambda: bridge.counters.master["state"] == "unreachable", 30, "the master's loss seen")
        ros_master.start()
        wait_for(lambda: bridge.counters.master["restarts"] == 1, 30, "the restarted master seen")
        burst_recorded(bridge, ros_master, "/after")  # a new topic, on the new master
        assert latched_command(ros_master) == {"state": "first"}, "a late subscriber gets the latched one"
        send_command(operator.amqp_url, {"state": "current"})
        assert latched_command(ros_master) == {"state": "current"}
        assert bridge.counters.snapshot()["topics"]["/after"]["dropped"] == {}

        # the ROS side killed, and unable to start for a while (its Python gone): restarted with
        # backoff, and `ros status` says so (exit 1) until it runs again
        options = bridge.options
        bridge.options = dataclasses.replace(options, python="/nonexistent/python3")
        assert bridge._process is not None
        os.kill(bridge._process.pid, signal.SIGKILL)

        def side_in_file() -> dict[str, Any]:  # what `fleetbus ros status` reads
            return json.loads(bridge.status_file.read_text())["parts"]["ros-side"]

        # the bridge writes its status file just after its counters change: wait for the file itself
        wait_for(
            lambda: (
                (p := side_in_file())["state"] == "restarting"
                and "/nonexistent/python3" in p.get("last_failure", "")
            ),
            30,
            "the failed restart noted in the status file",
        )
        status = fleetbus(bus, "ros", "status", "rosres1")
        assert status.returncode == 1, status.stdout + status.stderr
        part = json.loads(status.stdout)["parts"]["ros-side"]
        assert part["state"] == "restarting" and part["failures"] >= 2, part  # killed, then not started
        assert 0 < part["retry_in"] <= 30 and "cannot start the ROS side" in part["last_failure"]
        bridge.options = options
        wait_for(lambda: bridge.counters.parts.snapshot()["ros-side"]["state"] == "running", 60, "restarted")
        assert bridge.counters.parts.snapshot()["ros-side"]["restarts"] == 1
        burst_recorded(bridge, ros_master, "/again")  # recording resumes
        # the new ROS side latches what the last one had: a node subscribing now gets it
        assert latched_command(ros_master) == {"state": "current"}
        bridge.report()
        status = fleetbus(bus, "ros", "status", "rosres1")
        assert status.returncode == 0, status.stdout + status.stderr
        shown = json.loads(status.stdout)
        assert {name: part["state"] for name, part in shown["parts"].items()} == {
            "ros-side": "running",
            "ros-log": "running",
            "writer": "running",
            "notifications": "running",
            "commands": "running",
        }
    assert bridge._process is not None and bridge._process.poll() is not None, "its ROS side ended with it"


def bridge_node(master: RosMaster) -> str | None:
    """The bridge's ROS node, as ``rosnode list`` names it (anonymous: ``/fleetbus_bridge_...``)."""
    listed = subprocess.run(["rosnode", "list"], env=master.env, capture_output=True, text=True, timeout=60)
    return next((name for name in listed.stdout.split() if name.startswith("/fleetbus_bridge")), None)


def test_a_ros_side_whose_node_is_shut_down_from_outside_is_started_again(
    bus: Bus, ros_master: RosMaster
) -> None:
    robot = bus.robot(bus.add("rosres2", kind=RobotKind.EXPLORER))
    with running_bridge(robot, ros_master, bus.settings.robots_dir, include=("/revived",)) as bridge:
        first = bridge._process
        assert first is not None
        node = wait_for(lambda: bridge_node(ros_master), 30, "the bridge's node listed by the master")
        # what an operator's `rosnode kill` does: the master's XML-RPC `shutdown` call to the node
        killed = subprocess.run(
            ["rosnode", "kill", node], env=ros_master.env, capture_output=True, text=True, timeout=60
        )
        assert killed.returncode == 0 and "killed" in killed.stdout, killed.stdout + killed.stderr

        def side() -> dict[str, Any]:
            return bridge.counters.parts.snapshot()["ros-side"]

        wait_for(
            lambda: side()["restarts"] == 1 and side()["state"] == "running", 60, "the ROS side restarted"
        )
        assert first.poll() == 70, "the shut down ROS side ended itself, saying why"
        assert "the ROS node was shut down" in side()["last_failure"], side()
        burst_recorded(bridge, ros_master, "/revived")  # the new ROS side records
        bridge.report()
        status = fleetbus(bus, "ros", "status", "rosres2")
        assert status.returncode == 0, status.stdout + status.stderr
        shown = json.loads(status.stdout)
        part = shown["parts"]["ros-side"]
        assert shown["ros_side"] == "running" and part["state"] == "running" and part["restarts"] == 1
        assert "external shutdown request" in part["last_failure"], part
        assert "(ros side)" not in shown["topics"], "rospy's print of the request kept out of the lines"
    assert bridge.counters.ros_side == "ended (0)", "the bridge's own stop is no failure of its ROS side"
    assert bridge.counters.parts.snapshot()["ros-side"]["restarts"] == 1


def shut_down(master: RosMaster, node: str, reason: str) -> None:
    """What `rosnode kill` does, with a reason of our own: the node's XML-RPC ``shutdown`` call
    (the ROS side's rospy prints ``shutdown request: <reason>`` to its log)."""
    code, _, uri = xmlrpc.client.ServerProxy(master.uri).lookupNode("/test", node)
    assert code == 1, f"{node} is not registered: {uri}"
    with contextlib.suppress(ConnectionError):  # it may end before it answers: its log says it did
        xmlrpc.client.ServerProxy(uri).shutdown("/test", reason)


def new_bridge_node(master: RosMaster, gone: set[str]) -> str | None:
    listed = subprocess.run(["rosnode", "list"], env=master.env, capture_output=True, text=True, timeout=60)
    return next(
        (n for n in listed.stdout.split() if n.startswith("/fleetbus_bridge") and n not in gone), None
    )


def shut_down_the_side(bridge: Any, master: RosMaster, gone: set[str], n: int, restarted: bool) -> None:
    """Shut down the running ROS side's node (not one in ``gone``: it is added), as the ``n``-th
    time; wait for its line in the log and, if ``restarted``, for the next ROS side."""
    node = wait_for(lambda: new_bridge_node(master, gone), 30, f"ROS side {n}'s node listed")
    shut_down(master, node, f"shutdown {n} of the test")
    gone.add(node)
    wait_for(lambda: f"shutdown {n} of the test" in bridge.ros_log.read_text(), 30, f"shutdown {n} logged")
    if restarted:
        wait_for(lambda: bridge.counters.parts.snapshot()["ros-side"]["restarts"] == n, 60, "restarted")


def test_the_ros_side_log_keeps_its_newest_lines_within_its_bound(bus: Bus, ros_master: RosMaster) -> None:
    """Shut down from outside again and again, the ROS side writes more to its log than the
    bound: the log and its older file each stay within it, 0600, and hold the newest lines."""
    robot = bus.robot(bus.add("rosres3", kind=RobotKind.EXPLORER))
    bound, shutdowns = 100, 5  # a line is "shutdown request: shutdown N of the test\n", 41 bytes
    with running_bridge(robot, ros_master, bus.settings.robots_dir, log_max_bytes=bound) as bridge:
        log, older = bridge.ros_log, bridge.ros_log.with_name("ros-side.log.1")
        gone: set[str] = set()
        for n in range(1, shutdowns + 1):
            shut_down_the_side(bridge, ros_master, gone, n, restarted=n < shutdowns)
        sizes = {path.name: path.stat().st_size for path in (older, log) if path.exists()}
        assert len(sizes) == 2 and max(sizes.values()) <= bound, f"over {bound} bytes: {sizes}"
        files = {path: path.read_bytes() for path in (older, log)}
        assert {path.name: stat.S_IMODE(path.stat().st_mode) for path in files} == {
            "ros-side.log.1": 0o600,
            "ros-side.log": 0o600,
        }
        kept = [int(m) for m in re.findall(rb"shutdown (\d+) of the test", b"".join(files.values()))]
        assert kept == list(range(shutdowns - len(kept) + 1, shutdowns + 1)) and len(kept) >= 2, files
        assert ROS_LOG_TOPIC not in bridge.counters.snapshot()["topics"], "no line of the log dropped"


def test_without_a_master_the_ros_side_ends_when_the_bridge_stops_or_is_killed(
    ros_installed: None, tmp_path: Path
) -> None:
    absent = RosMaster(tmp_path)  # never started
    # the bridge stops: it closes the ROS side's input
    side = subprocess.Popen(
        [ROS_PYTHON, str(ROS_SIDE), "--parent", str(os.getpid())],
        env=absent.env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    read_line(side, '{"kind":"master"', 30)  # it started, and found no master
    assert side.stdin is not None
    side.stdin.close()
    assert side.wait(30) == 0
    # the bridge is killed: the ROS side ends with it, its input still open (another process holds it)
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import os, subprocess, sys; "
            "side = subprocess.Popen([*sys.argv[1:], '--parent', str(os.getpid())], "
            "stdout=subprocess.DEVNULL); "
            "print(side.pid, flush=True); sys.stdin.read()",
            ROS_PYTHON,
            str(ROS_SIDE),
        ],
        env=absent.env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert parent.stdout is not None
        pid = int(parent.stdout.readline())
        parent.kill()  # at once: before or after the ROS side asked to end with it
        parent.wait()
        wait_for(lambda: not os.path.exists(f"/proc/{pid}") or zombie(pid), 30, "the ROS side to end")
    finally:
        if parent.stdin is not None:
            parent.stdin.close()


def zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ", 1)[1].startswith("Z")
    except FileNotFoundError:
        return True
