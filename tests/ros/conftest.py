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
from pathlib import Path

import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.ros.bridge import Bridge, BridgeOptions
from fleetbus.publishers.ros.mapping import Mapping, load_mapping
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


class RosMaster:
    """``roscore`` on a port of its own, its logs in ``folder``; stopped and started again at will
    (a restart: a new master process on the same URI)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.port = free_port()
        self.uri = f"http://127.0.0.1:{self.port}"
        ros = {"ROS_MASTER_URI": self.uri, "ROS_HOME": str(folder / "ros"), "ROS_IP": "127.0.0.1"}
        self.env = {**os.environ, **ros}
        self.env.pop("ROS_HOSTNAME", None)
        self.core: subprocess.Popen[bytes] | None = None

    def answers(self) -> bool:
        try:
            return xmlrpc.client.ServerProxy(self.uri).getSystemState("/test")[0] == 1
        except OSError:
            return False

    def start(self) -> None:
        log = self.folder / "roscore.log"
        core = subprocess.Popen(
            ["roscore", "-p", str(self.port)],
            env=self.env,
            stdout=log.open("ab"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.core = core

        def up() -> bool:
            assert core.poll() is None, f"roscore ended ({core.returncode}): see {log}"
            return self.answers()

        wait_for(up, 30, "the ROS master to answer")

    def stop(self) -> None:
        core, self.core = self.core, None
        if core is None:
            return
        os.killpg(core.pid, signal.SIGINT)  # roscore stops its master and rosout
        try:
            core.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(core.pid, signal.SIGKILL)
            core.wait()
        wait_for(lambda: not self.answers(), 15, "the ROS master gone")


@pytest.fixture
def ros_master(ros_installed: None, tmp_path: Path) -> Iterator[RosMaster]:
    """``roscore`` on a free port, its logs in the test's folder; stopped (with its nodes) after."""
    master = RosMaster(tmp_path)
    try:
        master.start()
        yield master
    finally:
        master.stop()


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
    robot: RobotClient,
    master: RosMaster,
    state_dir: Path,
    commands_url: str | None = None,
    mapping: Mapping | None = None,
    node_up: bool = True,
    **options: object,
) -> Iterator[Bridge]:
    """The bridge for ``robot`` on a thread, with the standard mapping unless given one; once its
    ROS node is up (``node_up``), else once its ROS side started; stopped (and checked) after."""
    settings = {"discover_every_s": 0.2, "status_every_s": 0.5, "ros_env": master.env, **options}
    rules = mapping or load_mapping(None)
    bridge = Bridge(robot, rules, BridgeOptions(**settings), state_dir, commands_url)  # type: ignore[arg-type]
    result: list[int | BaseException] = []

    def run() -> None:
        try:
            result.append(bridge.run())
        except BaseException as error:
            result.append(error)

    thread = threading.Thread(target=run, name="ros-bridge", daemon=True)
    thread.start()
    try:
        wanted = ("running",) if node_up else ("waiting for the master", "running")
        wait_for(lambda: bridge.counters.ros_side in wanted or result, 30, "the ROS side to start")
        assert not result, f"the bridge ended at its start: {result}"
        yield bridge
    finally:
        bridge.stop()
        thread.join(30)
        assert not thread.is_alive(), "the bridge did not stop"
    assert result == [0], f"the bridge ended with {result}"
