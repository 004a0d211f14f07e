"""Two fleetbus deployments on two private RabbitMQ nodes: a site and central, linked by the
site's shovels through a :class:`~tests.link.NetworkLink` the tests cut, restore and flap.

The nodes are session-scoped, started the first time a test of this process asks for them (two
boots cost seconds of CPU each), one pair per xdist worker (each in its temporary folder). Each
test gets a fresh virtual host on both, its own data directories (its own stores) and a link
of its own; the site's shovels reach central through the link.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from fleetbus_dev.local_node import LocalNode
from tests.console.conftest import browser, chromium  # noqa: F401  (the console's browser fixtures)
from tests.sites.pair import SitePair, open_pair


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


@pytest.fixture
def pair(site_node: LocalNode, central_node: LocalNode, tmp_path: Path) -> Iterator[SitePair]:
    """A site ``base1`` and central, each with a fresh virtual host and store; the site's links to
    central go through ``pair.link``. Robots are added with :meth:`SitePair.add_robot`."""
    with open_pair(site_node, central_node, tmp_path) as pair:
        yield pair
