"""A site's accounts from central's registry, and a site whose central is a cluster: on two real
nodes, through `fleetbus sites` at central and `fleetbus site` at the site."""

from __future__ import annotations

import json
from urllib.parse import urlsplit, urlunsplit

import pytest

from fleetbus.broker.accounts import save_secret
from fleetbus.broker.management import ManagementError
from fleetbus.broker.sites import local_uri
from fleetbus.publishers.addresses import join_addresses
from fleetbus.schemas.routing import DOWNLINK_SHOVEL, UPLINK_SHOVEL, site_downlink_queue
from tests.commands import Ran, fleetbus
from tests.sites.pair import SitePair
from tests.support import Bus, wait_for


def _password(url: str) -> str:
    return urlsplit(url).password or ""


def _on_port(url: str, port: int) -> str:
    parts = urlsplit(url)
    login = parts.netloc.rpartition("@")[0]
    return urlunsplit((parts.scheme, f"{login}@127.0.0.1:{port}", parts.path, parts.query, ""))


def _add_site(central: Bus, site: str, *robots: str) -> Ran:
    for robot in robots:
        central.api.delete_user(robot)  # broker-wide: one an aborted run left
        central.accounts.append(robot)
        assert fleetbus(central, "users", "add", robot, "--kind", "explorer").returncode == 0
    added = fleetbus(central, "sites", "add", site, "--robots", ",".join(robots))
    assert added.returncode == 0, added.stderr
    central.accounts.append(site)
    return added


def test_sites_add_sends_its_robots_accounts_and_a_removed_robot_leaves_it(pair: SitePair) -> None:
    added = _add_site(pair.central, "base6", "roamer1")
    assert "sent base6 the accounts of roamer1" in added.stdout
    assert pair.central.ready_messages(site_downlink_queue("base6")) == 1, "its account waits for the site"
    assert (
        pair.central.api.get_permissions(pair.central.vhost, "base6")["write"]
        == "^((roamer1)\\.(events|beacon)|base6\\.(status|hazards))$"
    )
    assert fleetbus(pair.central, "users", "remove", "roamer1").returncode == 0
    assert (
        pair.central.api.get_permissions(pair.central.vhost, "base6")["write"]
        == "^(base6\\.(status|hazards))$"
    )
    assert fleetbus(pair.central, "users", "check").returncode == 0, "the site no longer has it"


def test_a_site_whose_central_is_a_cluster_connects_to_it(pair: SitePair) -> None:
    central, site = pair.central, pair.site
    added = _add_site(central, "base7", "roamer2")
    # central as a cluster of two nodes: the link's address and the node's own, one URL
    url = next(line for line in added.stdout.splitlines() if line.startswith("amqp://base7:"))
    over_link = pair.over_tls(url)
    direct = _on_port(over_link, pair.central_node.ports()["amqps"])  # type: ignore[index]
    cluster = join_addresses([over_link, direct])
    url_file = site.settings.data_dir / "central.url"
    save_secret(url_file, cluster)
    up = fleetbus(site, "site", "up", "--name", "base7", "--central-file", str(url_file))
    assert _password(url) not in up.stdout + up.stderr, "the password is never shown"
    assert up.returncode == 0, up.stderr
    uplink = site.api.get_shovel(site.vhost, UPLINK_SHOVEL)
    assert uplink is not None and len(uplink["dest-uri"]) == 2, "one URI per node"

    def site_status() -> dict:  # type: ignore[type-arg]
        shown = fleetbus(site, "site", "status", "--json")
        assert shown.returncode == 0, shown.stderr
        return json.loads(shown.stdout)

    def running(name: str) -> dict | None:  # type: ignore[type-arg]
        return next((s for s in site.api.shovel_status(site.vhost) if s["name"] == name), None)

    # the shovels that run are base7's, not the fixture's base1 ones that `site up` replaced
    wait_for(
        lambda: (running(DOWNLINK_SHOVEL) or {}).get("src_queue") == site_downlink_queue("base7"),
        what="base7's downlink running in place of base1's",
    )
    wait_for(lambda: site_status()["uplink"]["state"] == "running", what="the uplink to the cluster running")
    downlink = site.api.get_shovel(site.vhost, DOWNLINK_SHOVEL)
    assert downlink is not None and len(downlink["src-uri"]) == 2
    wait_for(
        lambda: central.ready_messages(site_downlink_queue("base7")) == 0,
        what="the site's downlink to take roamer2's account from the cluster",
    )


def test_a_refused_shovel_never_shows_its_password(bus: Bus) -> None:
    definition = {
        "src-protocol": "amqp091",
        "src-uri": "amqp://base8:topsecret1@127.0.0.1:5672,127.0.0.1:5673/%2F",  # not one URI
        "src-queue": "nowhere",
        "dest-protocol": "amqp091",
        "dest-uri": local_uri(bus.vhost),
        "dest-queue": "nowhere",
    }
    with pytest.raises(ManagementError) as refused:
        bus.api.put_shovel(bus.vhost, "refused", definition)
    assert "base8:****@" in str(refused.value) and "topsecret1" not in str(refused.value)
