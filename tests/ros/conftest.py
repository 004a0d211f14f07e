"""A real ROS 1 master for the bridge's tests, ROS nodes under the ROS machine's Python, the bridge."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import threading
import xmlrpc.client
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.ros.bridge import Bridge, BridgeOptions
from fleetbus.publishers.ros.mapping import load_mapping
from tests.api.server import free_port
from tests.support import read_line, wait_for

ROS_PYTHON = "/usr/bin/python3"
PEER = Path(__file__).with_name("ros_peer.py")


def ros_missing() -> str | None:
    if shutil.which("roscore") is None:
        return "roscore is not installed"
    check = subprocess.run([ROS_PYTHON, "-c", "import rospy, rostopic"], capture_output=True)
    return "rospy is not installed for /usr/bin/python3" if check.returncode else None


@pytest.fixture(scope="session")
def ros_installed() -> None:
    """ROS 1 must be there when the run asked for it (scripts/test installs it); else the tests skip."""
    missing = ros_missing()
    if missing and os.environ.get("FLEETBUS_WITH_ROS") == "1":
        pytest.fail(f"FLEETBUS_WITH_ROS=1 but {missing}: scripts/setup should have installed it")
    if missing:
        pytest.skip(f"{missing} (FLEETBUS_WITH_ROS=1 bash scripts/setup installs ROS 1)")


@dataclass
class RosMaster:
    uri: str
    env: dict[str, str]


@pytest.fixture
def ros_master(ros_installed: None, tmp_path: Path) -> Iterator[RosMaster]:
    """``roscore`` on a free port, its logs in the test's folder; stopped (with its nodes) after."""
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(tmp_path / "ros"), "ROS_IP": "127.0.0.1"}
    env.pop("ROS_HOSTNAME", None)
    core = subprocess.Popen(
        ["roscore", "-p", str(port)],
        env=env,
        stdout=(tmp_path / "roscore.log").open("wb"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )

    def answers() -> bool:
        assert core.poll() is None, f"roscore ended ({core.returncode}): see {tmp_path / 'roscore.log'}"
        try:
            return xmlrpc.client.ServerProxy(uri).getSystemState("/test")[0] == 1
        except OSError:
            return False

    try:
        wait_for(answers, 30, "the ROS master to answer")
        yield RosMaster(uri, env)
    finally:
        os.killpg(core.pid, signal.SIGINT)  # roscore stops its master and rosout
        try:
            core.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(core.pid, signal.SIGKILL)
            core.wait()


@contextmanager
def ros_peer(master: RosMaster, *args: str) -> Iterator[subprocess.Popen[str]]:
    """A ROS node (``ros_peer.py``) under /usr/bin/python3, ready; ended by closing its input."""
    node = subprocess.Popen(
        [ROS_PYTHON, str(PEER), *args],
        env=master.env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        read_line(node, '"ready"', 30)
        yield node
    finally:
        assert node.stdin is not None
        node.stdin.close()
        try:
            node.wait(10)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()


@contextmanager
def running_bridge(
    robot: RobotClient, master: RosMaster, state_dir: Path, commands_url: str | None = None, **options: object
) -> Iterator[Bridge]:
    """The bridge for ``robot`` on a thread, with the standard mapping; stopped (and checked) after."""
    settings = {"discover_every_s": 0.2, "status_every_s": 0.5, "ros_env": master.env, **options}
    bridge = Bridge(robot, load_mapping(None), BridgeOptions(**settings), state_dir, commands_url)  # type: ignore[arg-type]
    result: list[int | BaseException] = []

    def run() -> None:
        try:
            result.append(bridge.run())
        except BaseException as error:
            result.append(error)

    thread = threading.Thread(target=run, name="ros-bridge", daemon=True)
    thread.start()
    try:
        wait_for(lambda: bridge.counters.ros_side != "starting" or result, 30, "the ROS side to start")
        yield bridge
    finally:
        bridge.stop()
        thread.join(30)
        assert not thread.is_alive(), "the bridge did not stop"
    assert result == [0], f"the bridge ended with {result}"
