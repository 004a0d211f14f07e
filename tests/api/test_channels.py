"""Mount, check-in, check-out and unmount through the API, with the real worker, broker and store:
what reaches whom, what is recorded under which mission, and whether the broker's bindings are
what the service believes (read back through the management API)."""

from __future__ import annotations

import json
import logging
import threading
import uuid
from collections.abc import Iterator

import pika
import pika.exceptions
import pytest

from fleetbus.broker.accounts import Account, Role
from fleetbus.broker.mounts import QueueBinding, mount_bindings_on_broker
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.api.support import READY_PLAN, Api, running_api_on_each_store
from tests.factories import hazard
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

S = MissionState


@pytest.fixture(params=["sqlite", "mongodb"])
def api(request: pytest.FixtureRequest, bus: Bus) -> Iterator[Api]:
    """The team on the test's broker slice; the store is SQLite or MongoDB (the worker shares it)."""
    with running_api_on_each_store(request, bus) as running:
        running.user("admin1", UserRole.ADMIN)
        running.user("client1", UserRole.CLIENT)
        running.user("super1", UserRole.SUPERVISOR)
        running.user("oper1", UserRole.OPERATOR)
        running.user("oper2", UserRole.OPERATOR)
        created = running.call(
            "admin1",
            "POST",
            "/users",
            json={"name": "explorer1", "role": "robot", "kind": "explorer", "password": None},
        )
        assert created.status_code == 201, created.text
        yield running


def robot_url(api: Api, name: str) -> str:
    user = api.run(lambda: api.service.repositories.users.get_user(name))
    assert user is not None
    return api.service.accounts.broker_credentials(user).amqp_url


def step(api: Api, who: str, mission_id: str, to: S) -> dict:
    reply = api.call(who, "POST", f"/missions/{mission_id}/transitions", json={"to": to.value})
    assert reply.status_code == 200, reply.text
    return reply.json()


def approved_mission(api: Api) -> str:
    created = api.call(
        "client1",
        "POST",
        "/missions",
        json={"use_case": "hazard-response", "title": "Fire", "plan": READY_PLAN},
    )
    assert created.status_code == 201, created.text
    mission_id = created.json()["mission_id"]
    step(api, "client1", mission_id, S.FILED)
    step(api, "super1", mission_id, S.APPROVED)
    return mission_id


def broker_bindings(api: Api) -> set[QueueBinding]:
    return mount_bindings_on_broker(api.bus.api, api.bus.vhost)


def test_events_are_recorded_under_the_mission_only_while_checked_in(api: Api) -> None:
    mission_id = approved_mission(api)
    mounted = api.call("oper1", "POST", "/mounts", json={"robot": "explorer1", "mission_id": mission_id})
    assert mounted.status_code == 201, mounted.text
    assert broker_bindings(api) == {
        QueueBinding("explorer1.events", "oper1.stream", "#"),
        QueueBinding("oper1.commands", "explorer1.commands", "explorer1.#"),
    }
    # an operator with a robot mounted stays one: its mount is on its stream and commands exchange
    demoted = api.call("admin1", "PUT", "/users/oper1/role", json={"role": "client"})
    assert demoted.status_code == 409 and "oper1 is in use" in demoted.json()["detail"], demoted.text
    explorer = api.bus.robot(Account("explorer1", Role.ROBOT, robot_url(api, "explorer1")))

    def stored_and_recorded(count: int) -> bool:
        return api.bus.count("hazard") == count and len(api.bus.recorded("hazard")) == count

    with api.bus.worker(), api.bus.recorder():
        explorer.publish_many([("hazard", hazard(i)) for i in range(2)])  # mounted, not checked in
        wait_for(lambda: stored_and_recorded(2), what="2 hazards before check-in")
        refused = api.call("oper1", "POST", f"/missions/{mission_id}/check-in")
        assert (refused.status_code, refused.json()["detail"]) == (
            409,
            f"mission {mission_id} is approved; operators check in while it is in_progress",
        )
        step(api, "super1", mission_id, S.IN_PROGRESS)
        assert api.call("oper1", "POST", f"/missions/{mission_id}/check-in").status_code == 200
        explorer.publish_many([("hazard", hazard(i)) for i in range(2, 5)])
        wait_for(lambda: stored_and_recorded(5), what="3 hazards after check-in")
        out = api.call("oper1", "POST", f"/missions/{mission_id}/check-out")
        assert out.status_code == 200 and out.json()["operators_left"] == 0
        assert out.json()["mission"]["state"] == "reviewing", "the last operator out: the mission is reviewed"
        explorer.publish("hazard", hazard(5))
        wait_for(lambda: stored_and_recorded(6), what="a hazard after check-out")
        hazards = {
            h["robot_id"] + f":{h['seq']}": h
            for h in api.call("super1", "GET", f"/missions/{mission_id}/events").json()
        }
    stored = api.bus.find(EventQuery(type="hazard"))
    assert [(r.seq, r.mission_id) for r in stored] == [
        (0, None),
        (1, None),
        (2, mission_id),
        (3, mission_id),
        (4, mission_id),
        (5, None),
    ]
    recorded = {r.seq: r.mission_id for r in api.bus.recorded("hazard")}
    assert recorded == {r.seq: r.mission_id for r in stored}, "the recording carries the same missions"
    assert [r.seq for r in api.bus.recorded("hazard", mission_id=mission_id)] == [2, 3, 4]
    assert sorted(hazards) == ["explorer1:2", "explorer1:3", "explorer1:4"]
    assert {(h["user_id"], h["exchange"], h["routing_key"]) for h in hazards.values()} == {
        ("explorer1", "explorer1.events", "explorer1.hazard")
    }
    numbered = api.run(lambda: api.service.repositories.hazards.open_hazards(mission_id))
    assert [(h.hazard_id, h.seq) for h in numbered] == [(1, 2), (2, 3), (3, 4)], "hazard ids per mission"
    # the command line lists them all, as GET /hazards does, each with its mission
    every = [("default", n) for n in (1, 2, 3)] + [(mission_id, n) for n in (1, 2, 3)]
    for only, expected in ((None, every), (mission_id, every[3:])):
        listed = fleetbus(api.bus, "hazards", "--json", *(["--mission", only] if only else []))
        assert listed.returncode == 0, listed.stderr
        rows = [json.loads(line) for line in listed.stdout.splitlines()]
        assert [(r["mission_id"], r["hazard_id"]) for r in rows] == expected, rows
    actions = [
        (c.actor, c.action.value)
        for c in api.run(lambda: api.service.repositories.channels.channel_changes(mission_id))
    ]
    assert actions == [("oper1", "mount"), ("oper1", "check-in"), ("oper1", "check-out")]
    report = api.call("super1", "GET", "/channels/bindings").json()
    assert report["consistent"] and len(report["expected"]) == 2


def test_a_booked_robot_or_operator_cannot_be_mounted_again(api: Api) -> None:
    first, second = approved_mission(api), approved_mission(api)
    assert (
        api.call("oper1", "POST", "/mounts", json={"robot": "explorer1", "mission_id": first}).status_code
        == 201
    )
    api.user("explorer2", UserRole.ROBOT, RobotKind.EXPLORER)
    cases = [
        ("oper2", "explorer1", first, f"robot explorer1 is mounted by oper1 for mission {first}"),
        ("oper1", "explorer2", second, f"operator oper1 is booked by mission {first}"),
    ]
    for operator, robot, mission_id, detail in cases:
        reply = api.call(operator, "POST", "/mounts", json={"robot": robot, "mission_id": mission_id})
        assert (reply.status_code, reply.json()["detail"]) == (409, detail)
    planning = api.call(
        "client1", "POST", "/missions", json={"use_case": "hazard-response", "title": "x"}
    ).json()
    reply = api.call(
        "oper2", "POST", "/mounts", json={"robot": "explorer2", "mission_id": planning["mission_id"]}
    )
    assert (reply.status_code, reply.json()["detail"]) == (
        409,
        f"mission {planning['mission_id']} is planning; "
        "robots can be mounted when it is approved, in_progress, interrupted",
    )
    assert broker_bindings(api) == {
        QueueBinding("explorer1.events", "oper1.stream", "#"),
        QueueBinding("oper1.commands", "explorer1.commands", "explorer1.#"),
    }


def test_of_two_operators_mounting_at_once_one_gets_the_robot(api: Api) -> None:
    mission_id = approved_mission(api)
    api.token("oper1"), api.token("oper2")
    results: dict[str, int] = {}

    def mount(operator: str) -> None:
        results[operator] = api.call(
            operator, "POST", "/mounts", json={"robot": "explorer1", "mission_id": mission_id}
        ).status_code

    threads = [threading.Thread(target=mount, args=(name,)) for name in ("oper1", "oper2")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert sorted(results.values()) == [201, 409], results
    [winner] = [name for name, status in results.items() if status == 201]
    assert broker_bindings(api) == {
        QueueBinding("explorer1.events", f"{winner}.stream", "#"),
        QueueBinding(f"{winner}.commands", "explorer1.commands", "explorer1.#"),
    }


def send_command(url: str, operator: str, robot: str, name: str) -> None:
    connection = blocking_connection(url)
    try:
        confirms = PipelinedConfirms(connection, connection.channel(), timeout=10)
        properties = pika.BasicProperties(delivery_mode=2, user_id=operator, message_id=uuid.uuid4().hex)
        confirms.publish(
            [Outgoing(f"{operator}.commands", f"{robot}.{name}", b'{"speed": 0}', properties)], 10
        )
    finally:
        if connection.is_open:
            connection.close()


def test_commands_reach_only_a_mounted_robot_and_a_supervisor_can_force_an_unmount(
    api: Api, caplog: pytest.LogCaptureFixture
) -> None:
    mission_id = approved_mission(api)
    operator_url = robot_url(api, "oper1")
    with pytest.raises(PublishRefused, match="unroutable"):
        send_command(operator_url, "oper1", "explorer1", "stop")  # not mounted: nowhere to go
    api.call("oper1", "POST", "/mounts", json={"robot": "explorer1", "mission_id": mission_id})
    send_command(operator_url, "oper1", "explorer1", "stop")
    robot = blocking_connection(robot_url(api, "explorer1"))
    method, properties, body = robot.channel().basic_get("explorer1.commands", auto_ack=True)
    robot.close()
    assert method is not None and (method.exchange, method.routing_key, properties.user_id, body) == (
        "oper1.commands",
        "explorer1.stop",
        "oper1",
        b'{"speed": 0}',
    )
    with caplog.at_level(logging.WARNING, "fleetbus.api.security"):
        other = api.call("oper2", "DELETE", "/mounts/explorer1")
    assert (other.status_code, other.json()["detail"]) == (
        403,
        "robot explorer1 is mounted by oper1; only they or a supervisor can unmount it",
    )
    assert any(
        "DELETE /mounts/explorer1" in r.getMessage() and "oper2 (operator)" in r.getMessage()
        for r in caplog.records
    )
    forced = api.call("super1", "DELETE", "/mounts/explorer1")
    assert forced.status_code == 200 and forced.json()["operator"] == "oper1"
    assert broker_bindings(api) == set(), "the unmount removed both bindings"
    with pytest.raises(PublishRefused, match="unroutable"):
        send_command(operator_url, "oper1", "explorer1", "go")
    [change] = [
        c
        for c in api.run(lambda: api.service.repositories.channels.channel_changes(mission_id))
        if c.actor == "super1"
    ]
    assert (change.action.value, change.operator, change.robot) == ("force-unmount", "oper1", "explorer1")


def test_the_broker_bindings_are_checked_against_the_service_and_repaired(api: Api) -> None:
    mission_id = approved_mission(api)
    api.call("oper1", "POST", "/mounts", json={"robot": "explorer1", "mission_id": mission_id})
    # behind the service's back: one mount binding removed, one binding no mount explains added
    api.bus.api.unbind(api.bus.vhost, "explorer1.events", "oper1.stream", "#")
    api.bus.api.bind(api.bus.vhost, "explorer1.events", "oper2.stream", "#")
    report = api.call("super1", "GET", "/channels/bindings").json()
    assert (report["consistent"], report["missing"], report["unexpected"]) == (
        False,
        ["explorer1.events --#--> oper1.stream"],
        ["explorer1.events --#--> oper2.stream"],
    )
    repaired = api.call("super1", "POST", "/channels/bindings/repair").json()
    assert repaired["consistent"] and broker_bindings(api) == {
        QueueBinding("explorer1.events", "oper1.stream", "#"),
        QueueBinding("oper1.commands", "explorer1.commands", "explorer1.#"),
    }
    last = api.run(lambda: api.service.repositories.channels.channel_changes(limit=1))[0]
    assert last.action.value == "repair" and "oper2.stream" in last.detail


def test_the_mission_moves_to_reviewing_only_when_its_last_operator_checks_out(api: Api) -> None:
    mission_id = approved_mission(api)
    step(api, "super1", mission_id, S.IN_PROGRESS)
    for operator in ("oper1", "oper2"):
        assert api.call(operator, "POST", f"/missions/{mission_id}/check-in").status_code == 200
    first = api.call("oper1", "POST", f"/missions/{mission_id}/check-out").json()
    assert (first["operators_left"], first["mission"]["state"]) == (1, "in_progress")
    again = api.call("oper1", "POST", f"/missions/{mission_id}/check-out")
    assert (again.status_code, again.json()["detail"]) == (
        409,
        f"oper1 is not checked in to mission {mission_id}",
    )
    last = api.call("oper2", "POST", f"/missions/{mission_id}/check-out").json()
    assert (last["operators_left"], last["mission"]["state"]) == (0, "reviewing")
    history = api.call("client1", "GET", f"/missions/{mission_id}").json()["history"]
    assert history[-1]["by"] == "fleetbus" and history[-1]["note"] == "every operator checked out"
