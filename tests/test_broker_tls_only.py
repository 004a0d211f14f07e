"""A private node with ``FLEETBUS_BROKER_TLS_ONLY``: no plain port accepts a login, and the whole
path (robot, worker, store, management API) works over TLS alone."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import httpx
import pytest

from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.probe import amqp_login
from fleetbus.schemas.routing import RobotKind
from fleetbus_dev.local_node import HOST, LocalNode, listening_addresses
from tests.factories import status
from tests.run_tls import run_tls_files, suite_endpoint
from tests.support import fresh_bus, wait_for


@pytest.fixture(scope="module")
def tls_only_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalNode]:
    node = LocalNode(tmp_path_factory.mktemp("tls-only") / "broker", run_tls_files(), tls_only=True)
    node.up()
    try:
        yield node
    finally:
        node.kill()  # a throwaway node: no need for a clean shutdown's seconds
        node.down()


def test_no_plain_port_listens_and_a_plain_login_is_refused(tls_only_node: LocalNode) -> None:
    info = tls_only_node.status()
    assert info.pid is not None and info.amqp_url is not None and info.management_url is not None
    assert info.amqp_url.startswith("amqps://") and info.management_url.startswith("https://")
    listening = {port for _, port in listening_addresses(info.pid)}
    assert {info.ports["amqps"], info.ports["management_tls"]} <= listening
    assert not {info.ports["amqp"], info.ports["management"]} & listening
    user, password = (quote(part, safe="") for part in tls_only_node.admin_credentials() or ("", ""))
    assert amqp_login(f"amqp://{user}:{password}@{HOST}:{info.ports['amqp']}/") is None, "plain AMQP answered"
    assert amqp_login(info.amqp_url, timeout=10) is True  # a TLS handshake on a loaded machine
    with pytest.raises(httpx.ConnectError):
        httpx.get(f"http://{HOST}:{info.ports['management']}/api/overview", timeout=5)


def test_robots_and_the_worker_work_over_tls_alone(tls_only_node: LocalNode, tmp_path: Path) -> None:
    endpoint = suite_endpoint(tls_only_node.status())
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        fresh_bus(endpoint, api, tmp_path) as bus,
    ):
        account = bus.add("explorer1", kind=RobotKind.EXPLORER)
        assert account.amqp_url.startswith("amqps://")
        robot = bus.robot(account)
        with bus.worker():
            for _ in range(3):
                robot.publish("status", status())
            wait_for(lambda: bus.count() == 3, what="the three statuses stored")
