"""The console script as a user types it, against the real broker."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import yaml

from fleetbus.schemas.routing import EventType
from fleetbus.schemas.services import METHODS
from tests.api.server import free_port
from tests.commands import fleetbus as in_process
from tests.factories import hazard, status
from tests.support import Bus, wait_for


def fleetbus(bus: Bus, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m fleetbus ARGS`` in the bus's environment (and ``env``'s variables on top)."""
    env = {**os.environ, **bus.worker_env(), "COLUMNS": "200", **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "fleetbus", *args], env=env, capture_output=True, text=True, timeout=120
    )


def test_users_publish_query_and_dlq(bus: Bus, tmp_path: Path) -> None:
    bus.accounts.append("cli-explorer")
    added = fleetbus(bus, "users", "add", "cli-explorer", "--kind", "explorer")
    assert added.returncode == 0, added.stderr
    assert re.search(r"amqps?://cli-explorer:", added.stdout)
    assert "fleetbus-demo" not in added.stdout
    again = fleetbus(bus, "users", "add", "cli-explorer")
    assert again.returncode == 1 and "exists" in again.stderr
    # a new password keeps what the account is: a robot, an explorer (as the console's re-key does)
    rotated = fleetbus(bus, "users", "add", "cli-explorer", "--rotate")
    assert rotated.returncode == 0, rotated.stderr
    assert "gave a new password to robot cli-explorer" in rotated.stdout
    users = json.loads(fleetbus(bus, "users", "list", "--json").stdout)["users"]
    [listed] = [u for u in users if u["name"] == "cli-explorer"]
    assert (listed["role"], listed["kind"]) == ("robot", "explorer")

    data = tmp_path / "hazard.yaml"
    data.write_text(yaml.safe_dump(hazard()))
    with bus.worker(), bus.recorder():
        published = fleetbus(bus, "publish", "cli-explorer", "hazard", f"@{data}")
        assert published.returncode == 0, published.stderr
        wait_for(lambda: bus.count() == 1, what="the published hazard to be stored")
        wait_for(lambda: bus.recorded("hazard"), what="the published hazard to be recorded")
        bad = fleetbus(
            bus, "publish", "cli-explorer", "hazard", json.dumps({**hazard(), "pose": {"x": "a", "y": 1}})
        )
        assert bad.returncode == 2
        assert "body.pose.x" in bad.stderr
    found = fleetbus(bus, "query", "hazard", "--robot", "cli-explorer", "--json")
    assert found.returncode == 0, found.stderr
    [line] = found.stdout.splitlines()
    assert json.loads(line)["body"]["description"] == "Fire"
    table = fleetbus(bus, "query", "hazard")
    assert "cli-explorer" in table.stdout and "1 hazard events" in table.stdout
    letters = fleetbus(bus, "dlq", "--json")
    assert letters.returncode == 0 and letters.stdout == ""


def test_schema_export(bus: Bus, tmp_path: Path) -> None:
    result = fleetbus(bus, "schemas", str(tmp_path))
    assert result.returncode == 0, result.stderr
    written = {path.name for path in tmp_path.glob("*.schema.json")}
    assert written == {"event.schema.json", *(f"{t.value}.schema.json" for t in EventType)}
    asyncapi = json.loads((tmp_path / "asyncapi.json").read_text())
    assert set(asyncapi["channels"]) == {
        *(f"{{robot}}.{t.value}" for t in EventType),  # beacons included, on their own exchange
        *(f"{{robot}}.{method.name}" for method in METHODS),
        "{robot}.inbox",
        "amq.rabbitmq.reply-to",
        "{robot}.{command}",
        "{user}.stream",
        "notify.{topic}",
        "fleetbus.beacon.discarded",
        "fleetbus.dead-letters",
        "fleetbus.ingest.events",
        "fleetbus.ingest.express",
        "fleetbus.recorder",
    }
    text = json.dumps(asyncapi)
    targets = {
        f"#/components/{kind}/{name}"
        for kind in ("schemas", "messages", "messageTraits")
        for name in asyncapi["components"][kind]
    }
    assert set(re.findall(r'"\$ref": "([^"]+)"', text)) <= targets, "every $ref resolves"


def test_a_password_on_the_command_line_is_refused_naming_where_it_goes(bus: Bus) -> None:
    """Every user of the machine sees a command's arguments: a robot's URL with its password is
    taken from FLEETBUS_ROBOT_URL or the kept file, never from --url."""
    bus.accounts.append("argv-explorer")
    assert fleetbus(bus, "users", "add", "argv-explorer", "--kind", "explorer").returncode == 0
    kept = (bus.settings.accounts_dir / "argv-explorer.url").read_text().strip()
    refused = fleetbus(bus, "publish", "argv-explorer", "status", json.dumps(status()), "--url", kept)
    assert refused.returncode == 2
    said = refused.stderr.replace("\n", " ")
    assert "--url holds a password" in said and "FLEETBUS_ROBOT_URL" in said, said
    assert kept.split("@")[0].rsplit(":", 1)[1] not in refused.stderr, "the password is not repeated"
    by_bridge = in_process(bus, "ros", "bridge", "argv-explorer", "--url", kept)  # refused first thing
    assert by_bridge.returncode == 2 and "--url holds a password" in by_bridge.stderr.replace("\n", " ")
    for command, instead in (
        (["tail"], "FLEETBUS_USER_URL"),
        (["replay", "--to", "x", "--since", "1h"], "FLEETBUS_AMQP_URL"),
    ):
        other = fleetbus(bus, *command, "--url", kept)
        said = other.stderr.replace("\n", " ")
        assert other.returncode == 2 and "--url holds a password" in said and instead in said, said
    # in the environment it is taken, by the ROS bridge too (it gets as far as starting its ROS side)
    bridge = fleetbus(
        bus,
        "ros",
        "bridge",
        "argv-explorer",
        env={"FLEETBUS_ROBOT_URL": kept, "FLEETBUS_ROS_PYTHON": "/nonexistent/python"},
    )
    said = bridge.stderr.replace("\n", " ")
    assert bridge.returncode == 1 and "cannot start the ROS side with '/nonexistent/python'" in said, said


def test_a_robots_url_option_is_declared_once_for_every_command_that_takes_it() -> None:
    from fleetbus.cli.commands.events import publish
    from fleetbus.cli.commands.ros import bridge
    from fleetbus.cli.options import RobotUrl

    for command in (publish, bridge):
        assert typing.get_type_hints(command, include_extras=True)["url"] == RobotUrl, command.__name__


def test_a_part_that_fails_under_a_command_is_named_as_the_http_api_names_it(bus: Bus) -> None:
    """The broker's management API away: the command says so in the API's words (its 503), with
    no traceback."""
    listed = fleetbus(
        bus, "users", "list", env={"FLEETBUS_MANAGEMENT_URL": f"http://127.0.0.1:{free_port()}/"}
    )
    assert listed.returncode == 1
    assert "the broker's management API is unreachable" in listed.stderr.replace("\n", " "), listed.stderr
    assert "Traceback" not in listed.stderr
