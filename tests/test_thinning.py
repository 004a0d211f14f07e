"""After an outage the robot sends hazards and localisations before the telemetry that waited
longer; the telemetry beyond the outbox's limit (``FLEETBUS_OUTBOX_LIMITS``) is thinned to its
newest, and what was dropped reaches the operators' team view with the robot's next status."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.routing import INGEST_EXCHANGE, RobotKind
from fleetbus.workers.team import read_team
from tests.factories import hazard, status
from tests.support import Bus, wait_for

ARRIVALS = "test.arrivals"


def test_after_an_outage_hazards_go_first_and_the_team_view_shows_what_was_dropped(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FLEETBUS_OUTBOX_LIMITS", "status=500")
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    with bus.admin_channel() as channel:  # sees the robot's events in the order the broker got them
        channel.queue_declare(ARRIVALS)
        channel.queue_bind(ARRIVALS, INGEST_EXCHANGE, "explorer1.#")
    robot = RobotClient(account.amqp_url, state_dir=bus.settings.robots_dir)
    bus.clients.append(robot)
    # the outage: the client not started, its outbox filling
    waited = robot.build(
        [("status", status())] * 1000
        + [("hazard", hazard(0))]
        + [("status", status())] * 200
        + [("localisation", {"localised": True})]
    )
    robot.outbox.append(waited)
    assert robot.outbox.dropped() == {"status": 700}, "the oldest status events beyond 500 dropped"
    robot.start()
    assert robot.flush(60)
    arrived: list[str] = []
    with bus.admin_channel() as channel:
        for method, properties, _ in channel.consume(ARRIVALS, inactivity_timeout=30):
            if method is None:
                break
            arrived.append(properties.type)
            if len(arrived) == 502:
                break
    kept = [event for event in waited if event.type.value == "status"][-500:]
    assert arrived == ["hazard", "localisation"] + ["status"] * 500
    with bus.worker():
        sent = robot.publish("status", status())
        assert sent.body.outbox_dropped == {"status": 700}, "the client says so in its status"
        wait_for(lambda: bus.count("status") == 501, what="the statuses stored")
        [member] = bus.with_store(
            lambda store: read_team(
                store.hazards, store.events, datetime.now(timezone.utc), timedelta(minutes=1)
            )
        )
    assert member.robot.name == "explorer1" and member.outbox_dropped == {"status": 700}
    assert [r.seq for r in bus.find() if r.type == "status"][:500] == [e.seq for e in kept]
