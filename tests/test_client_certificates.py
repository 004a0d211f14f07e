"""A robot that logs in with its client certificate (EXTERNAL) instead of a password, end to end:
on a node started by this code (certificate logins are offered from a node's start on), its
hazard reaches the worker and is stored as the robot's."""

from __future__ import annotations

import pytest

from fleetbus.broker.accounts import can_login
from fleetbus.broker.certificates import ClientFiles, issue_client_certificate
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import split_tls, with_client_certificate
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.factories import hazard
from tests.run_tls import BROKER_TLS, run_tls_files
from tests.support import Bus, wait_for

pytestmark = pytest.mark.skipif(not BROKER_TLS, reason="certificate logins need the broker's TLS listener")


def certificate_robot(bus: Bus, name: str) -> str:
    """A robot account with no password, and the URL that logs in with its client certificate."""
    bus.accounts.append(name)
    made = bus.with_accounts(
        lambda accounts: accounts.provision(
            name, UserRole.ROBOT, RobotKind.EXPLORER, "tests", rotate=True, certificate=True
        )
    )
    client = ClientFiles.in_folder(bus.settings.data_dir / "clients", name)
    issue_client_certificate(run_tls_files(), client, name)
    return with_client_certificate(made.internal_url, client.cert, client.key)


def test_a_robot_with_its_client_certificate_publishes_and_the_worker_stores_it(killable_bus: Bus) -> None:
    bus = killable_bus
    url = certificate_robot(bus, "explorer1")
    _, tls = split_tls(url)
    assert tls is not None and tls.external and ":" not in url.split("@")[0].removeprefix("amqps://")
    with bus.worker(), RobotClient(url, state_dir=bus.settings.robots_dir, connect_timeout=20) as robot:
        robot.connect()
        robot.publish("hazard", hazard())
        assert robot.flush(timeout=20)
        wait_for(lambda: bus.count("hazard", "explorer1") == 1, what="the robot's hazard stored")


def test_rotate_with_a_certificate_takes_the_password_away(killable_bus: Bus) -> None:
    """`users add NAME --cert --rotate` on an account that logs in with a password: afterwards only
    its certificate does."""
    bus = killable_bus
    with_password = bus.add("explorer2", kind=RobotKind.EXPLORER).amqp_url
    assert can_login(with_password)
    url = certificate_robot(bus, "explorer2")
    assert not can_login(with_password)
    assert can_login(url)
