"""The live ROS bridge against ``rosbag record`` on the same topics, in the same run.

    .venv/bin/python -m bench.ros_bridge [--seconds 20] [--small-hz 1000] [--image-hz 10] [--small-bytes N]
    .venv/bin/python -m bench.ros_bridge --small-hz 100 --small-bytes 480 --image-hz 0   # the reference's

A private ROS master; a ROS node publishes small std_msgs/String messages at ``--small-hz`` and a
640x480 rgb8 sensor_msgs/Image at ``--image-hz``; `fleetbus ros bridge` (a process, as on a robot,
with a robot account on a fresh virtual host and a worker storing what arrives) and
`rosbag record` both subscribe to the two topics. Reported per topic: messages sent, recorded by
each (the bridge's counts, the bag's contents), the bridge's drops by reason, messages per second
recorded; and the CPU (% of one core) and peak resident memory of each recorder (the bridge with
its ROS side; rosbag with its recorder process). Both keep images' pixels whole (the bridge up to
``FLEETBUS_ROS_BLOB_MAX_BYTES``, as ``ros_chunk`` events). Measured, not asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from bench.proc import cpu_seconds, rss_megabytes
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker
from tests.support import fresh_bus, wait_for

ROS_PYTHON = "/usr/bin/python3"
# a script for the ROS machine's Python, not a module of the bench (it imports rospy)
PUBLISHER = Path(__file__).parent / "ros_nodes" / "publisher.py"
TOPICS = ("/bench/small", "/bench/image")
ROBOT = "bench-ros"
console = Console()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def family(pid: int) -> list[int]:
    """``pid`` and its descendants now."""
    pids, todo = [], [pid]
    while todo:
        current = todo.pop()
        pids.append(current)
        for task in Path(f"/proc/{current}/task").glob("*"):
            children = (task / "children").read_text().split() if (task / "children").exists() else []
            todo += [int(c) for c in children]
    return pids


class Cost:
    """CPU seconds and peak RSS of a process and its children, sampled (children come and go)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.cpu: dict[int, float] = {}
        self.rss_peak = 0.0
        self.rss_peaks: dict[int, float] = {}
        self.names: dict[int, str] = {}

    def sample(self) -> None:
        total = 0.0
        for pid in family(self.pid):
            try:
                self.cpu[pid] = cpu_seconds(pid)
                rss = rss_megabytes(pid)
                total += rss
                self.rss_peaks[pid] = max(self.rss_peaks.get(pid, 0.0), rss)
                if pid not in self.names:
                    words = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
                    self.names[pid] = " ".join(Path(w.decode()).name for w in words[:4] if w)
            except (FileNotFoundError, ProcessLookupError):
                continue
        self.rss_peak = max(self.rss_peak, total)

    def cpu_total(self) -> float:
        return sum(self.cpu.values())


def bag_counts(path: Path) -> dict[str, int]:
    code = (
        "import json, sys, rosbag; b = rosbag.Bag(sys.argv[1]); "
        "print(json.dumps({t: i.message_count for t, i in b.get_type_and_topic_info().topics.items()}))"
    )
    out = subprocess.run([ROS_PYTHON, "-c", code, str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def run(seconds: float, small_hz: float, image_hz: float, small_bytes: int = 0) -> dict[str, Any]:
    endpoint = resolve_broker(load_settings(), start=True)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        port = free_port()
        env = {**os.environ, "ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_HOME": str(tmp / "ros")}
        core = subprocess.Popen(
            ["roscore", "-p", str(port)],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])

        def master_up() -> bool:
            try:
                return master.getSystemState("/bench")[0] == 1
            except OSError:
                return False

        try:
            wait_for(master_up, 30, "the ROS master")
            with (
                ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
                fresh_bus(endpoint, api, tmp / "fleetbus", "bench") as bus,
                bus.worker(),
            ):
                account = bus.add(ROBOT, kind=RobotKind.EXPLORER)
                bridge_env = {
                    **bus._env(),
                    **{k: v for k, v in env.items() if k.startswith("ROS_")},
                    "FLEETBUS_ROS_INCLUDE": " ".join(TOPICS),
                    "FLEETBUS_ROS_STATUS_EVERY_S": "1",
                    "FLEETBUS_ROBOT_URL": account.amqp_url,  # a password is never an argument
                }
                bridge = subprocess.Popen(
                    [sys.executable, "-m", "fleetbus", "ros", "bridge", ROBOT],
                    env=bridge_env,
                    stdout=subprocess.DEVNULL,
                    stderr=(tmp / "bridge.log").open("wb"),
                )
                bag = tmp / "bench.bag"
                rosbag = subprocess.Popen(
                    ["rosbag", "record", "-O", str(bag), *TOPICS],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
                status_file = bus.settings.robots_dir / ROBOT / "ros-bridge.json"
                publisher = subprocess.Popen(
                    [ROS_PYTHON, str(PUBLISHER), *map(str, (seconds, small_hz, image_hz, 2, small_bytes))],
                    env=env,
                    stdout=subprocess.PIPE,
                    text=True,
                )
                assert publisher.stdout is not None
                json.loads(publisher.stdout.readline())  # both recorders subscribed: it starts
                costs = {"bridge": Cost(bridge.pid), "rosbag": Cost(rosbag.pid)}
                for cost in costs.values():
                    cost.sample()
                before = {name: cost.cpu_total() for name, cost in costs.items()}
                started = time.monotonic()
                while publisher.poll() is None:
                    for cost in costs.values():
                        cost.sample()
                    time.sleep(0.25)  # sampling period
                report = json.loads(publisher.stdout.readline())
                wall = time.monotonic() - started
                cpu = {name: 100 * (cost.cpu_total() - before[name]) / wall for name, cost in costs.items()}
                processes = {
                    f"{name}: {cost.names.get(pid, pid)}": {
                        "cpu_seconds": round(cost.cpu[pid], 2),
                        "rss_peak_mb": round(cost.rss_peaks.get(pid, 0.0), 1),
                    }
                    for name, cost in costs.items()
                    for pid in cost.cpu
                }
                sent = report["sent"]

                def settled() -> dict[str, Any] | None:
                    status = json.loads(status_file.read_text()) if status_file.exists() else None
                    topics = (status or {}).get("topics", {})
                    done = all(
                        t in topics and topics[t]["recorded"] + sum(topics[t]["dropped"].values()) >= sent[t]
                        for t in TOPICS
                    )
                    return status if done else None

                try:
                    status = wait_for(settled, 120, "the bridge to account for every message", 0.5)
                except AssertionError:
                    status = json.loads(status_file.read_text())
                os.killpg(rosbag.pid, signal.SIGINT)
                rosbag.wait(30)
                bridge.send_signal(signal.SIGTERM)
                bridge.wait(60)
                stored_by = time.monotonic()
                forwarded = sum(status["topics"][t]["recorded"] for t in TOPICS)
                try:
                    wait_for(lambda: bus.count("ros", ROBOT) >= forwarded, 300, "the store", 0.5)
                except AssertionError:
                    pass  # reported: how many the store holds
                store_lag = time.monotonic() - stored_by
                stored = bus.count("ros", ROBOT)
                in_bag = bag_counts(bag)
                return {
                    "seconds": report["seconds"],
                    "sent": sent,
                    "bridge": {t: status["topics"][t] for t in TOPICS},
                    "bag": in_bag,
                    "cpu": cpu,
                    "rss": {name: cost.rss_peak for name, cost in costs.items()},
                    "processes": processes,
                    "store_lag_s": store_lag,
                    "stored": stored,
                    "forwarded": forwarded,
                }
        finally:
            os.killpg(core.pid, signal.SIGINT)
            core.wait(30)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--small-hz", type=float, default=1000.0)
    parser.add_argument("--image-hz", type=float, default=10.0, help="0: no image topic")
    parser.add_argument("--small-bytes", type=int, default=0, help="text length of the small messages")
    args = parser.parse_args()
    result = run(args.seconds, args.small_hz, args.image_hz, args.small_bytes)
    table = Table(title=f"ROS bridge against rosbag record, {result['seconds']:.1f} s")
    for column in (
        "topic",
        "sent",
        "bridge recorded",
        "bridge msg/s",
        "bridge dropped",
        "rosbag recorded",
        "rosbag msg/s",
    ):
        table.add_column(column)
    for topic in TOPICS:
        b = result["bridge"][topic]
        table.add_row(
            topic,
            str(result["sent"][topic]),
            str(b["recorded"]),
            f"{b['recorded'] / result['seconds']:.0f}",
            ", ".join(f"{r} {n}" for r, n in b["dropped"].items()) or "0",
            str(result["bag"].get(topic, 0)),
            f"{result['bag'].get(topic, 0) / result['seconds']:.0f}",
        )
    console.print(table)
    for name in ("bridge", "rosbag"):
        console.print(
            f"{name}: CPU {result['cpu'][name]:.0f} % of one core, peak RSS {result['rss'][name]:.0f} MB"
        )
    if result["stored"] >= result["forwarded"]:
        lag = result["store_lag_s"]
        console.print(f"the store held every forwarded message {lag:.1f} s after the bridge stopped")
    else:
        console.print(f"the store held {result['stored']} of {result['forwarded']} forwarded messages")
    console.print_json(json.dumps(result))


if __name__ == "__main__":
    main()
