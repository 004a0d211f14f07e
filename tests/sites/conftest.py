"""Two fleetbus deployments on two private RabbitMQ nodes: a site and central, linked by the
site's shovels through a :class:`~tests.link.NetworkLink` the tests cut, restore and flap.

The nodes are session-scoped, started the first time a test of this process asks for them (two
boots cost seconds of CPU each), one pair per xdist worker (each in its temporary folder). Each
test gets a fresh virtual host on both, its own data directories (its own stores) and a link
of its own; the site's shovels reach central through the link.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.dev.local_node import LocalNode
from tests.console.conftest import browser, chromium  # noqa: F401  (the console's browser fixtures)
from tests.link import NetworkLink
from tests.sites.pair import SitePair
from tests.support import fresh_bus


def _node(factory: pytest.TempPathFactory, name: str) -> Iterator[LocalNode]:
    node = LocalNode(factory.mktemp(name) / "broker")
    node.up()
    try:
        yield node
    finally:
        node.kill()  # throwaway: no clean shutdown's seconds
        node.down()  # its epmd


@pytest.fixture(scope="session")
def site_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalNode]:
    yield from _node(tmp_path_factory, "site")


@pytest.fixture(scope="session")
def central_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalNode]:
    yield from _node(tmp_path_factory, "central")


def _endpoint(node: LocalNode) -> BrokerEndpoint:
    info = node.up()  # started again if an earlier test left it down
    assert info.amqp_url and info.management_url
    return BrokerEndpoint(info.amqp_url, info.management_url, "private")


@pytest.fixture
def pair(site_node: LocalNode, central_node: LocalNode, tmp_path: Path) -> Iterator[SitePair]:
    """A site ``base1`` and central, each with a fresh virtual host and store; the site's links to
    central go through ``pair.link``. Robots are added with :meth:`SitePair.add_robot`."""
    central_endpoint, site_endpoint = _endpoint(central_node), _endpoint(site_node)
    with (
        ManagementAPI.from_urls(central_endpoint.management_url, central_endpoint.amqp_url) as central_api,
        ManagementAPI.from_urls(site_endpoint.management_url, site_endpoint.amqp_url) as site_api,
        fresh_bus(central_endpoint, central_api, tmp_path / "central", prefix="central") as central,
        fresh_bus(site_endpoint, site_api, tmp_path / "site", prefix="site") as site,
    ):
        link = NetworkLink(central_node.ports()["amqps"]).start()  # type: ignore[index]  (TLS)
        pair = SitePair(site, central, link, "base1", site_node, central_node)
        try:
            asyncio.run(pair.join())
            yield pair
        finally:
            link.stop()
            pair.stop()
            site_node.up()
            central_node.up()
