"""Alerts over HTTP and the command line, with the real broker, worker and store: a robot's low
battery raised once per drop from the statuses it publishes, acknowledged once with who and when,
the same outcome through ``GET /alerts``, ``POST /alerts/{id}/acknowledge`` and ``fleetbus alerts``."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import Any

from fleetbus.broker.accounts import Account, Role
from fleetbus.broker.management import connections_by_user
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.api.support import PROBLEM_JSON, Api, running_api
from tests.api.test_channels import robot_url
from tests.commands import fleetbus
from tests.factories import hazard, status
from tests.support import Bus, wait_for


def alerts_of(api: Api, kind: str, acknowledged: bool = False) -> list[dict[str, Any]]:
    """The unacknowledged alerts of ``kind`` (with ``acknowledged``, the acknowledged ones): each
    GET /alerts runs the service's check first."""
    listed = api.call("oper1", "GET", "/alerts", params={"acknowledged": str(acknowledged).lower()})
    assert listed.status_code == 200, listed.text
    return [
        a for a in listed.json()["acknowledged" if acknowledged else "unacknowledged"] if a["kind"] == kind
    ]


def battery_alerts(api: Api) -> list[dict[str, Any]]:
    return alerts_of(api, "battery-low")


def test_a_low_battery_is_one_alert_per_drop_acknowledged_once_through_api_and_command_line(bus: Bus) -> None:
    # checked in the background once at start, then by each GET /alerts (and `fleetbus alerts`)
    with running_api(bus, bus.settings.updated(alerts_check_s=3600)) as api, bus.worker():
        for name, role in (("oper1", UserRole.OPERATOR), ("super1", UserRole.SUPERVISOR)):
            api.user(name, role)
        api.user("client1", UserRole.CLIENT)
        api.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        explorer = bus.robot(Account("explorer1", Role.ROBOT, robot_url(api, "explorer1")))
        events = api.service.repositories.events

        def publish_status(battery: float) -> None:
            explorer.publish("status", status(battery))  # each battery once in this test
            query = EventQuery(robot_id="explorer1", type="status")

            def stored() -> bool:
                found = api.run(lambda: events.find_events(query))
                return any(record.body["battery_percent"] == battery for record in found)

            wait_for(stored, what=f"the status with {battery} % stored")

        publish_status(15.0)
        [first] = battery_alerts(api)
        assert (first["subject"], first["detail"]) == ("robot explorer1", "battery 15 % (low below 20 %)")
        assert first["ended_at"] is None and first["acknowledged_by"] is None
        publish_status(12.0)
        assert [a["id"] for a in battery_alerts(api)] == [first["id"]], "still low: the same alert"
        publish_status(80.0)
        [ended] = battery_alerts(api)
        assert ended["id"] == first["id"] and ended["ended_at"] is not None, "ended, still to acknowledge"
        publish_status(10.0)
        again = battery_alerts(api)
        assert len(again) == 2 and again[0]["id"] == first["id"], "a second drop: a second alert"
        second = again[1]

        before = datetime.now(timezone.utc)
        acknowledged = api.call("oper1", "POST", f"/alerts/{first['id']}/acknowledge")
        assert acknowledged.status_code == 200, acknowledged.text
        at = datetime.fromisoformat(acknowledged.json()["acknowledged_at"])
        assert acknowledged.json()["acknowledged_by"] == "oper1"
        assert before <= at <= datetime.now(timezone.utc) and at.utcoffset() == timezone.utc.utcoffset(None)
        twice = api.call("super1", "POST", f"/alerts/{first['id']}/acknowledge")
        assert (twice.status_code, twice.headers["content-type"]) == (409, PROBLEM_JSON)
        already = f"alert {first['id']} was acknowledged already, by oper1 at "
        assert twice.json()["detail"].startswith(already)
        assert api.call("client1", "POST", f"/alerts/{second['id']}/acknowledge").status_code == 403
        missing = api.call("oper1", "POST", "/alerts/999999/acknowledge")
        assert (missing.status_code, missing.json()["detail"]) == (404, "no alert 999999")

        # the command line: the same alerts, and the same rule for who may acknowledge
        listed = fleetbus(bus, "alerts", "--all", "--json")
        assert listed.returncode == 0, listed.stderr
        document = json.loads(listed.stdout)
        assert [a["id"] for a in document["acknowledged"]] == [first["id"]]
        assert document["acknowledged"][0]["acknowledged_by"] == "oper1"
        assert second["id"] in [a["id"] for a in document["unacknowledged"]]
        refused = fleetbus(bus, "alerts", "ack", str(second["id"]), "--by", "client1")
        assert refused.returncode == 1 and "role client may not acknowledge alerts" in refused.stderr
        done = fleetbus(bus, "alerts", "ack", str(second["id"]), "--by", "super1")
        assert done.returncode == 0, done.stderr
        said = f"alert {second['id']} (battery-low, robot explorer1) acknowledged by super1 at "
        assert said in done.stdout
        again_cli = fleetbus(bus, "alerts", "ack", str(second["id"]))
        assert again_cli.returncode == 1 and "acknowledged already, by super1" in again_cli.stderr
        shown = api.call("oper1", "GET", "/alerts", params={"acknowledged": "true"}).json()
        assert [(a["id"], a["acknowledged_by"]) for a in shown["acknowledged"]] == [
            (second["id"], "super1"),
            (first["id"], "oper1"),
        ]
        assert battery_alerts(api) == []


def test_an_announced_hazard_is_an_alert_at_the_next_quick_look_of_the_hazards(bus: Bus) -> None:
    """The full look is an hour away here: the alert comes from the look at the hazards alone."""
    settings = bus.settings.updated(alerts_check_s=3600, alerts_hazard_check_s=0.2)
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with running_api(bus, settings) as api, bus.worker():
        warden.publish("localisation", {"localised": True})
        explorer.publish("hazard", hazard(0, "Fire"))
        alerts = api.service.repositories.alerts

        def announced() -> list[str]:
            return [a.detail for a in api.run(alerts.open_alerts) if a.kind == "hazard-announced"]

        [detail] = wait_for(announced, 30, "the hazard's alert, without a GET /alerts")
        assert detail == "Fire (detected by explorer1)"


def test_a_robot_whose_connection_dropped_is_an_alert_that_ends_when_it_connects_again(bus: Bus) -> None:
    """The check runs at each GET /alerts (the background one is an hour away); a robot that never
    connected raises nothing."""
    settings = bus.settings.updated(alerts_check_s=3600, alerts_disconnected_s=0.2)
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.add("scout1", kind=RobotKind.EXPLORER)
    with running_api(bus, settings) as api:
        api.user("oper1", UserRole.OPERATOR)

        def connected() -> int:
            return connections_by_user(bus.api, bus.vhost).get("explorer1", 0)

        explorer = bus.robot(account)
        wait_for(connected, what="explorer1's connection listed by the management API")
        assert alerts_of(api, "robot-disconnected") == [], "connected: no alert"
        explorer.close(flush_timeout=0)
        [alert] = wait_for(lambda: alerts_of(api, "robot-disconnected"), what="the disconnected alert")
        assert alert["subject"] == "robot explorer1" and alert["ended_at"] is None, alert
        assert alert["detail"].startswith("no broker connection since "), alert
        assert alert["detail"].endswith("(alert after 0.2 s)"), alert

        bus.robot(account)  # connects again: the condition ends, the alert waits to be acknowledged
        ended = wait_for(
            lambda: [a for a in alerts_of(api, "robot-disconnected") if a["ended_at"]], what="the alert ended"
        )
        assert [a["id"] for a in ended] == [alert["id"]]
        before = datetime.now(timezone.utc)
        acknowledged = api.call("oper1", "POST", f"/alerts/{alert['id']}/acknowledge")
        assert acknowledged.status_code == 200, acknowledged.text
        assert acknowledged.json()["acknowledged_by"] == "oper1"
        assert (
            before
            <= datetime.fromisoformat(acknowledged.json()["acknowledged_at"])
            <= datetime.now(timezone.utc)
        )
        assert alerts_of(api, "robot-disconnected") == []
        assert [a["id"] for a in alerts_of(api, "robot-disconnected", acknowledged=True)] == [alert["id"]]


def test_a_silent_robot_is_a_stale_alert_raised_by_the_check(bus: Bus) -> None:
    settings = bus.settings.updated(alerts_check_s=3600, stale_after_s=0.5)
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    with running_api(bus, settings) as api, bus.worker():
        api.user("oper1", UserRole.OPERATOR)
        [never] = alerts_of(api, "robot-stale")
        assert (never["subject"], never["detail"]) == (
            "robot explorer1",
            "never heard from (stale after 0.5 s)",
        )
        explorer.publish("status", status(80.0))

        def silent_since() -> list[dict[str, Any]]:
            return [a for a in alerts_of(api, "robot-stale") if a["detail"].startswith("silent since ")]

        [alert] = wait_for(silent_since, what="a stale alert after the robot's status")
        assert alert["subject"] == "robot explorer1" and alert["detail"].endswith("(stale after 0.5 s)")
        acknowledged = api.call("oper1", "POST", f"/alerts/{alert['id']}/acknowledge")
        assert (acknowledged.status_code, acknowledged.json()["acknowledged_by"]) == (200, "oper1")
