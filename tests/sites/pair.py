"""A site and its central for a test: robots at both, the site's links up, what arrived where."""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar
from urllib.parse import unquote, urlencode, urlsplit, urlunsplit

from fleetbus.broker.accounts import Account, Role, url_for
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import start_site_links, stop_site_links
from fleetbus.broker.uplink import CLASSES, bounds_of
from fleetbus.schemas.routing import DOWNLINK_QUEUE, UPLINK_SHOVEL, RobotKind
from fleetbus.workers.downlink import apply_downlink
from fleetbus.workers.store import Repositories
from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.sites import Forward
from fleetbus_dev.local_node import LocalNode
from tests.link import NetworkLink
from tests.run_tls import plain_endpoint
from tests.support import Bus, fresh_bus, wait_for

T = TypeVar("T")


@dataclass
class SitePair:
    site: Bus
    central: Bus
    link: NetworkLink
    name: str
    site_node: LocalNode
    central_node: LocalNode
    account: Account | None = None
    """The site's account at central (its URL goes to the site's shovels, through the link)."""
    robots: list[str] = field(default_factory=list)

    async def join(self) -> None:
        """Central makes the site's account (through the accounts service, as `fleetbus sites add`
        does); the site starts its links through :attr:`link`."""
        self.central.accounts.append(self.name)
        added = await asyncio.to_thread(
            self.central.with_accounts,
            lambda accounts: accounts.add_site(self.name, (), "tests", rotate=True),
        )
        self.account = Account(self.name, Role.SERVICE, added.internal_url)
        await self.start_links()

    @property
    def central_url(self) -> str:
        assert self.account is not None
        return self.over_tls(self.account.amqp_url)

    def over_tls(self, central_account_url: str) -> str:
        """A login at central as the site's shovels use it: over AMQPS through the link, verified
        against central's CA for the name its certificate carries (``localhost``), as in the field."""
        parts = urlsplit(self.link.url(central_account_url))
        query = urlencode(
            {"cacertfile": str(self.central_node.tls.ca), "server_name_indication": "localhost"}, safe="/"
        )
        return urlunsplit(("amqps", parts.netloc, parts.path, query, ""))

    async def start_links(self) -> None:
        settings = self.site.settings
        await start_site_links(
            self.site.admin_url,
            self.site.api,
            self.name,
            self.central_url,
            bounds=bounds_of(settings),
            rejected_max=settings.downlink_rejected_max,
            reconnect_delay_s=settings.site_reconnect_delay_s,
        )

    def stop(self) -> None:
        stop_site_links(self.site.api, self.site.vhost)

    def add_robot(self, name: str, kind: RobotKind) -> Account:
        """A robot of the site, as in the field: registered at central and given to the site
        (through the accounts service, as `fleetbus users add` and `fleetbus sites robots --add`
        do), its account made at the site from the downlink (as `fleetbus site apply` does), where
        it connects with central's password and its events are forwarded. Returns its site account."""
        central_account = self.central.add(name, Role.ROBOT, kind)
        self.robots.append(name)
        self.site.accounts.append(name)
        self.central.with_accounts(
            lambda accounts: accounts.change_site_robots(self.name, [name], (), "tests")
        )
        wait_for(lambda: self.site.ready_messages(DOWNLINK_QUEUE) == 1, what=f"{name}'s account, down")
        assert apply_downlink(self.site.settings, self.site.admin_url, self.site.api, idle_s=0.1) == 1
        password = unquote(urlsplit(central_account.amqp_url).password or "")
        return Account(name, Role.ROBOT, url_for(self.site.admin_url, name, password))

    def central_store(self, operation: Callable[[Repositories], Awaitable[T]]) -> T:
        return self.central.with_store(operation)

    # what arrived
    def central_keys(self, robot: str) -> Counter[tuple[str, int]]:
        return Counter((r.epoch, r.seq) for r in self.central.find(EventQuery(robot_id=robot)))

    def site_keys(self, robot: str) -> Counter[tuple[str, int]]:
        return Counter((r.epoch, r.seq) for r in self.site.find(EventQuery(robot_id=robot)))

    def forwards(self, robot: str | None = None) -> list[Forward]:
        return self.central_store(lambda repos: repos.sites.forwards(robot))

    def uplink_waiting(self) -> int:
        """Events ready in the site's uplink, every class."""
        return sum(self.site.ready_messages(uplink.queue) for uplink in CLASSES)

    def uplink_state(self) -> str | None:
        for shovel in self.site.api.shovel_status(self.site.vhost):
            if shovel.get("name") == UPLINK_SHOVEL:
                return str(shovel.get("state"))
        return None


def node_endpoint(node: LocalNode) -> BrokerEndpoint:
    return plain_endpoint(node.up())  # started again if an earlier user left it down


@contextmanager
def open_pair(
    site_node: LocalNode, central_node: LocalNode, folder: Path, name: str = "base1"
) -> Iterator[SitePair]:
    """A site ``name`` and central, each with a fresh virtual host and store under ``folder``; the
    site's links to central go through ``pair.link``. Both nodes are up again afterwards."""
    central_endpoint, site_endpoint = node_endpoint(central_node), node_endpoint(site_node)
    with (
        ManagementAPI.from_urls(central_endpoint.management_url, central_endpoint.amqp_url) as central_api,
        ManagementAPI.from_urls(site_endpoint.management_url, site_endpoint.amqp_url) as site_api,
        fresh_bus(central_endpoint, central_api, folder / "central", prefix="central") as central,
        fresh_bus(site_endpoint, site_api, folder / "site", prefix="site") as site,
    ):
        link = NetworkLink(central_node.ports()["amqps"]).start()  # type: ignore[index]  (TLS)
        pair = SitePair(site, central, link, name, site_node, central_node)
        try:
            asyncio.run(pair.join())
            yield pair
        finally:
            link.stop()
            pair.stop()
            site_node.up()
            central_node.up()
