"""A broker URL with several addresses: split in one place, and every client fails over along it."""

from __future__ import annotations

import asyncio
import logging
import socket

import httpx
import pytest

from fleetbus.broker.accounts import url_for
from fleetbus.broker.endpoint import BrokerEndpoint, derive_management_url
from fleetbus.broker.failover import FailoverConnection
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.tls import aio_connect, aio_connect_robust
from fleetbus.broker.urls import mask_password
from fleetbus.publishers.addresses import first_address, join_addresses, split_addresses
from fleetbus.publishers.tls import blocking_connection

CLUSTER = "amqp://u:p%40w@10.0.0.1:5672,10.0.0.2:5673,node3/fleet?heartbeat=5"


def test_a_url_with_several_addresses_is_one_url_per_node_in_order() -> None:
    assert split_addresses(CLUSTER) == [
        "amqp://u:p%40w@10.0.0.1:5672/fleet?heartbeat=5",
        "amqp://u:p%40w@10.0.0.2:5673/fleet?heartbeat=5",
        "amqp://u:p%40w@node3/fleet?heartbeat=5",
    ]
    assert join_addresses(split_addresses(CLUSTER)) == CLUSTER
    assert first_address(CLUSTER) == "amqp://u:p%40w@10.0.0.1:5672/fleet?heartbeat=5"
    assert split_addresses("amqp://u:p@h:1/v") == ["amqp://u:p@h:1/v"]


def test_another_login_and_the_masked_url_keep_every_address() -> None:
    assert (
        url_for(CLUSTER, "robot1", "s")
        == "amqp://robot1:s@10.0.0.1:5672,10.0.0.2:5673,node3/fleet?heartbeat=5"
    )
    assert mask_password(CLUSTER) == "amqp://u:****@10.0.0.1:5672,10.0.0.2:5673,node3/fleet?heartbeat=5"


def _closed_port() -> int:
    """A port nothing listens on (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _with_dead_node_first(url: str) -> str:
    dead = split_addresses(url)[0].replace(
        url.split("@", 1)[1].split("/", 1)[0], f"127.0.0.1:{_closed_port()}"
    )
    return join_addresses([dead, url])


def test_pika_and_aio_pika_connect_to_the_next_address_when_the_first_is_down(
    endpoint: BrokerEndpoint,
) -> None:
    url = _with_dead_node_first(endpoint.amqp_url)
    blocking_connection(url, connection_attempts=1, socket_timeout=2).close()

    async def both() -> int | None:
        plain = await aio_connect(url)
        await plain.close()
        robust = await aio_connect_robust(url)
        try:
            assert isinstance(robust, FailoverConnection)
            assert not robust.is_closed
            return robust.url.port
        finally:
            await robust.close()

    live = int(endpoint.amqp_url.split("@", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])
    assert asyncio.run(both()) == live, "the dead node is skipped"


def test_a_lost_robust_connection_tries_the_next_address_then_comes_back(
    endpoint: BrokerEndpoint, caplog: pytest.LogCaptureFixture
) -> None:
    """aio-pika's robust connection over [live, dead]: once lost, it tries the dead address next,
    fails, and reconnects to the live one, restoring itself (the worker's failover)."""
    url = _with_dead_node_first(endpoint.amqp_url)
    caplog.set_level(logging.INFO, logger="fleetbus.broker")

    async def lose_and_recover() -> int | None:
        robust = await aio_connect_robust(url, reconnect_interval=0.1)
        try:
            assert robust.transport is not None
            await robust.transport.connection.close()
            deadline = asyncio.get_running_loop().time() + 30
            while not (robust.connected.is_set() and "address 1 of 2" in caplog.text):
                assert asyncio.get_running_loop().time() < deadline, caplog.text
                await asyncio.sleep(0.05)
            channel = await robust.channel()
            await channel.close()
            return robust.url.port
        finally:
            await robust.close()

    live = int(endpoint.amqp_url.split("@", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])
    assert asyncio.run(lose_and_recover()) == live
    assert "address 2 of 2" in caplog.text, "the dead address was tried in between"


def test_the_management_client_goes_to_the_next_node_when_the_first_does_not_answer(
    endpoint: BrokerEndpoint,
) -> None:
    live = endpoint.management_url.split(",")[0]
    dead = f"{live.split(':')[0]}://127.0.0.1:{_closed_port()}/"
    with ManagementAPI.from_urls(join_addresses([dead, live]), endpoint.amqp_url) as api:
        assert api.base_url == dead
        assert api.get_vhost("/") is not None, "answered by the live node"
        assert api.base_url.rstrip("/") == live.rstrip("/"), "and it stays there"


def test_a_clusters_management_urls_follow_its_broker_addresses() -> None:
    assert derive_management_url(CLUSTER) == "http://10.0.0.1:15672,10.0.0.2:15672,node3:15672/"
    assert derive_management_url("amqps://u:p@a:5671,b:5671/") == "https://a:15671,b:15671/"
    assert derive_management_url("amqp://u:p@h:1/v") == "http://h:15672/"


class _ClosesOnce:
    """An httpx client whose first request finds its kept-alive connection closed by the node."""

    def __init__(self) -> None:
        self.sent: list[str] = []

    def request(self, method: str, path: str, **kwargs: object) -> httpx.Response:
        self.sent.append(method)
        if len(self.sent) == 1:
            raise httpx.RemoteProtocolError("Server disconnected without sending a response.")
        return httpx.Response(204)


def test_a_kept_alive_connection_the_node_closed_is_retried_once_for_a_repeatable_request() -> None:
    client = _ClosesOnce()
    answer = ManagementAPI._request_once_more(client, "DELETE", "vhosts/x")  # type: ignore[arg-type]
    assert answer.status_code == 204 and client.sent == ["DELETE", "DELETE"]
    once = _ClosesOnce()
    with pytest.raises(httpx.RemoteProtocolError):  # a POST may have been handled: not sent again
        ManagementAPI._request_once_more(once, "POST", "exchanges/x/y/publish")  # type: ignore[arg-type]
    assert once.sent == ["POST"]
