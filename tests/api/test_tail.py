"""``fleetbus tail``: an operator follows its own stream on the real broker: history first with
``--since``, then live messages, each with its origin; only what the service bound reaches it."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import threading
from datetime import datetime, timedelta, timezone
from urllib.parse import unquote, urlsplit

from typer.testing import CliRunner

from fleetbus.broker.accounts import Account, Role
from fleetbus.broker.tail import Seen, follow
from fleetbus.cli import app
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind, stream_queue
from tests.api.support import Api, running_api
from tests.factories import hazard, status
from tests.support import Bus, wait_for


def url_of(api: Api, name: str) -> str:
    user = api.run(lambda: api.service.repositories.users.get_user(name))
    assert user is not None
    return api.service.accounts.broker_credentials(user).amqp_url


def setup_team(api: Api) -> tuple[str, str]:
    api.user("oper1", UserRole.OPERATOR)
    api.user("client1", UserRole.CLIENT)
    for robot in ("explorer1", "explorer2"):
        api.user(robot, UserRole.ROBOT, RobotKind.EXPLORER)
    mission = api.mission(MissionState.APPROVED)
    reply = api.call(
        "oper1", "POST", "/mounts", json={"robot": "explorer1", "mission_id": mission.mission_id}
    )
    assert reply.status_code == 201, reply.text
    return url_of(api, "oper1"), mission.mission_id


def test_since_replays_history_then_live_messages_follow(bus: Bus) -> None:
    with running_api(bus) as api:
        operator_url, _ = setup_team(api)
        explorer1 = bus.robot(Account("explorer1", Role.ROBOT, url_of(api, "explorer1")))
        explorer2 = bus.robot(Account("explorer2", Role.ROBOT, url_of(api, "explorer2")))
        explorer1.publish_many([("hazard", hazard(0)), ("status", status()), ("hazard", hazard(1))])
        explorer2.publish("hazard", hazard(9))  # not mounted by oper1: never in its stream
        explorer1.publish("hazard", hazard(2))  # a sentinel after it: explorer2's would come before

        history: list[Seen] = []
        start = datetime.now(timezone.utc) - timedelta(minutes=10)
        asyncio.run(
            follow(operator_url, "*.hazard", since=start, on_message=history.append, count=3, idle_timeout=5)
        )
        assert [(s.user_id, s.exchange, s.routing_key) for s in history] == [
            ("explorer1", "explorer1.events", "explorer1.hazard")
        ] * 3
        assert [json.loads(s.body)["seq"] for s in history] == [0, 2, 3]

        live: list[Seen] = []
        ready = threading.Event()
        follower = threading.Thread(
            target=lambda: asyncio.run(
                follow(
                    operator_url, "#", on_message=live.append, count=2, idle_timeout=20, on_ready=ready.set
                )
            )
        )
        follower.start()
        assert ready.wait(20), "the live follower attached"
        explorer1.publish("status", status(50))
        explorer2.publish("beacon", {"beacon_id": "b1", "rssi": -60})  # beacons reach every operator
        follower.join(30)
        assert [(s.user_id, s.exchange, s.routing_key) for s in live] == [
            ("explorer1", "explorer1.events", "explorer1.status"),
            ("explorer2", "explorer2.beacon", "explorer2.beacon"),
        ], "live: only what came after, nothing replayed"


def test_the_tail_command_shows_each_messages_origin(bus: Bus) -> None:
    with running_api(bus) as api:
        operator_url, _ = setup_team(api)
        explorer1 = bus.robot(Account("explorer1", Role.ROBOT, url_of(api, "explorer1")))
        explorer1.publish_many([("hazard", hazard(0)), ("status", status(42))])
        result = CliRunner().invoke(
            app,
            ["tail", "explorer1.*", "--since", "10m", "--count", "2", "--idle", "5"],
            env={"FLEETBUS_USER_URL": operator_url, "COLUMNS": "200"},
        )
        assert result.exit_code == 0, result.output
        lines = result.output.splitlines()
        assert lines[0].startswith("following 'explorer1.*' since ")
        assert "explorer1 via explorer1.events explorer1.hazard seq 0" in lines[1]
        assert (
            "explorer1 via explorer1.events explorer1.status seq 1" in lines[2]
            and '"battery_percent":42' in lines[2]
        )
        json_result = CliRunner().invoke(
            app,
            ["tail", "--since", "10m", "--count", "1", "--idle", "5", "--json"],
            env={"FLEETBUS_USER_URL": operator_url},
        )
        assert json.loads(json_result.output.splitlines()[0])["exchange"] == "explorer1.events"


def test_a_user_without_a_stream_is_told_so(bus: Bus) -> None:
    with running_api(bus) as api:
        api.user("client1", UserRole.CLIENT)
        result = CliRunner().invoke(
            app, ["tail", "--idle", "1"], env={"FLEETBUS_USER_URL": url_of(api, "client1")}
        )
    assert result.exit_code == 1
    assert (
        "no stream to follow" in result.output and "only operators and supervisors have one" in result.output
    )


def test_the_tail_command_says_so_and_fails_when_the_broker_closes_its_connection(bus: Bus) -> None:
    """Not an end as after ``--idle`` (status 0, nothing said): a script or a person watching
    would take the silence for a quiet stream."""
    with running_api(bus) as api:
        operator_url, _ = setup_team(api)
        tail = subprocess.Popen(
            [sys.executable, "-m", "fleetbus", "tail"],
            env={**os.environ, "FLEETBUS_USER_URL": operator_url},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            wait_for(
                lambda: any(
                    c["queue"]["name"] == stream_queue("oper1") for c in bus.api.list_consumers(bus.vhost)
                ),
                what="the tail following",
            )
            user = unquote(urlsplit(operator_url).username or "")
            # the management API lists a new connection a moment after its consumer
            wait_for(lambda: bus.api.close_connections_of(user, "an administrator closed it"), what="closed")
            out, err = tail.communicate(timeout=30)
        finally:
            tail.kill()
    assert tail.returncode == 1, out + err
    said = " ".join(err.split())
    assert (
        "error: the broker closed the connection: CONNECTION_FORCED - an administrator closed it" in said
    ), said
