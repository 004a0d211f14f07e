"""No split brain: a configured broker that does not answer is waited for, then an error; nothing
else is started or used in its place (README, "Configuration").

Each command runs as its own process, as a user runs it, with ``FLEETBUS_AMQP_URL`` (or the
worker's ``FLEETBUS_SERVICE_URL``) on a loopback port where nothing listens.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleetbus.broker.accounts import RECORDER_USER, SERVICE_USER, save_secret
from fleetbus.settings import load_settings
from fleetbus_dev.local_node import LocalNode
from tests.support import PROJECT_ROOT

WAIT_S = 3.0
#: Python's start, the last probe and a loaded machine, on top of the wait.
SLACK_S = 25.0
PASSWORD = "s3cret-admin-pw"


def dead_port() -> int:
    """A loopback port nothing listens on (bound, then let go)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def environment(data_dir: Path, **settings: str) -> dict[str, str]:
    env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(data_dir), FLEETBUS_BROKER_WAIT_S=str(WAIT_S), COLUMNS="200", **settings)
    return env


def run(command: list[str], env: dict[str, str]) -> tuple[subprocess.CompletedProcess[str], float]:
    started = time.monotonic()
    result = subprocess.run(
        command,
        env=env,
        cwd=PROJECT_ROOT,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=WAIT_S + SLACK_S + 60,
    )
    return result, time.monotonic() - started


def assert_started_nothing(data_dir: Path) -> None:
    settings = load_settings({"FLEETBUS_DATA_DIR": str(data_dir)})
    assert not (settings.broker_dir / "node.json").exists(), "a private broker node was made"
    assert LocalNode(settings.broker_dir).pid() is None, "a private broker node runs"
    assert not (settings.broker_dir / "docker-password").exists(), "the Docker broker was looked for"
    assert not settings.sqlite_path.exists() and not settings.recording_path.exists(), "a store was opened"


FLEETBUS = [sys.executable, "-m", "fleetbus"]
COMMANDS = {
    "worker": [*FLEETBUS, "worker"],
    "recorder": [*FLEETBUS, "recorder", "run"],
    "api": [*FLEETBUS, "api", "--port", "0"],
    "users add": [*FLEETBUS, "users", "add", "nobody-here"],
    "demo": [*FLEETBUS, "demo"],
    "broker status": [*FLEETBUS, "broker", "status"],
    "broker up": [*FLEETBUS, "broker", "up"],
    "setup": [*FLEETBUS, "setup"],
    "scripts/setup": ["bash", "scripts/setup"],
}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_configured_broker_that_does_not_answer_is_waited_for_then_an_error(
    name: str, tmp_path: Path
) -> None:
    port = dead_port()
    url = f"amqp://fleetbus-admin:{PASSWORD}@127.0.0.1:{port}/"
    for account in (SERVICE_USER, RECORDER_USER):  # so that the worker and recorder get as far as the broker
        save_secret(tmp_path / "accounts" / f"{account}.password", PASSWORD)
    result, took = run(COMMANDS[name], environment(tmp_path, FLEETBUS_AMQP_URL=url))
    output = result.stdout + result.stderr
    assert result.returncode != 0, output
    assert WAIT_S <= took < WAIT_S + SLACK_S, f"{name} ended after {took:.1f} s: {output}"
    assert f":****@127.0.0.1:{port}/" in output and "did not answer" in output, output
    assert "waiting for" in output, f"{name} did not say what it waits for: {output}"
    assert PASSWORD not in output, "a password was shown"
    assert_started_nothing(tmp_path)


def test_the_worker_waits_for_its_own_configured_broker(tmp_path: Path) -> None:
    port = dead_port()
    service_url = f"amqp://{SERVICE_USER}:{PASSWORD}@127.0.0.1:{port}/"
    result, took = run(COMMANDS["worker"], environment(tmp_path, FLEETBUS_SERVICE_URL=service_url))
    output = result.stdout + result.stderr
    assert result.returncode != 0 and WAIT_S <= took < WAIT_S + SLACK_S, output
    assert f"{SERVICE_USER}:****@127.0.0.1:{port}/" in output and PASSWORD not in output, output
    assert_started_nothing(tmp_path)


@pytest.mark.parametrize(
    "setting", ["FLEETBUS_SERVICE_URL", "FLEETBUS_MANAGEMENT_URL"], ids=["service URL", "management URL"]
)
def test_an_administrator_command_with_only_another_broker_setting_does_not_look_elsewhere(
    setting: str, tmp_path: Path
) -> None:
    value = f"amqp://{SERVICE_USER}@127.0.0.1:{dead_port()}/"
    result, _ = run(COMMANDS["users add"], environment(tmp_path, **{setting: value}))
    assert result.returncode != 0
    assert f"{setting} is set but FLEETBUS_AMQP_URL is not" in result.stderr, result.stderr
    assert_started_nothing(tmp_path)


#: ``fleetbus`` as the runtime wheel alone runs it: no ``fleetbus.local_broker`` entry point (the
#: development tooling's private node) is installed.
WITHOUT_DEV_TOOLING = """
import importlib.metadata as metadata, sys
found = metadata.entry_points
metadata.entry_points = lambda **kw: [] if kw.get("group") == "fleetbus.local_broker" else found(**kw)
from fleetbus.cli import app
sys.argv[0] = "fleetbus"
app()
"""


def test_without_the_development_tooling_an_unconfigured_broker_is_an_error_naming_the_setting(
    tmp_path: Path,
) -> None:
    command = [sys.executable, "-c", WITHOUT_DEV_TOOLING, "users", "add", "nobody-here"]
    result, _ = run(command, environment(tmp_path))
    assert result.returncode != 0
    assert "no broker is configured: set FLEETBUS_AMQP_URL" in result.stderr, result.stderr
    assert_started_nothing(tmp_path)
