"""The suite runs over TLS (``FLEETBUS_TEST_TLS``, on unless set to 0): this checks that it really
does, by asking the broker how each of the test's connections came in."""

from __future__ import annotations

import pytest

from fleetbus.schemas.routing import RobotKind
from tests.factories import status
from tests.run_tls import BROKER_TLS
from tests.support import Bus, wait_for

pytestmark = pytest.mark.skipif(not BROKER_TLS, reason="FLEETBUS_TEST_TLS=0: the run is over plain AMQP")


def test_robots_workers_and_the_administrator_connect_over_verified_tls(bus: Bus) -> None:
    assert bus.admin_url.startswith("amqps://") and "cacertfile=" in bus.admin_url
    assert bus.endpoint.management_url.startswith("https://")
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    assert account.amqp_url.startswith("amqps://")
    robot = bus.robot(account)
    with bus.worker():
        robot.publish("status", status())
        wait_for(lambda: bus.count() == 1, what="the status stored")
        connections = wait_for(
            lambda: (
                [c for c in bus.api.list_connections() if c.get("vhost") == bus.vhost and "ssl" in c] or None
            ),
            what="the test's connections listed",
        )
    users = {c["user"]: c["ssl"] for c in connections}
    assert users.get("explorer1") is True, users
    assert all(users.values()), f"a connection over plain AMQP: {users}"
