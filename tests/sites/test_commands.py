"""`fleetbus sites` on central and `fleetbus site` on the site, as an operator runs them."""

from __future__ import annotations

import json

from fleetbus.broker.accounts import save_secret
from fleetbus.broker.sites import forward_robot
from fleetbus.schemas.routing import UPLINK_SHOVEL, RobotKind
from tests.commands import fleetbus as run
from tests.factories import status
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_cli import fleetbus


def test_sites_add_site_up_and_both_views_of_the_link(pair: SitePair) -> None:
    central, site = pair.central, pair.site
    central.add("explorer2", kind=RobotKind.EXPLORER)
    added = fleetbus(central, "sites", "add", "base2", "--robots", "explorer2")
    assert added.returncode == 0, added.stderr
    central.accounts.append("base2")
    url = next(line for line in added.stdout.splitlines() if line.startswith("amqp://base2:"))
    in_argv = fleetbus(site, "site", "up", "--name", "base2", "--central", pair.over_tls(url))
    assert in_argv.returncode == 2 and "--central-file" in in_argv.stderr, "no password in argv"
    assert "base2" not in json.dumps(site.api.get_shovel(site.vhost, UPLINK_SHOVEL)), "nothing changed"
    url_file = site.settings.data_dir / "central.url"
    save_secret(url_file, pair.over_tls(url))
    up = fleetbus(site, "site", "up", "--name", "base2", "--central-file", str(url_file))
    assert up.returncode == 0, up.stderr
    assert "****" in up.stdout and url.split("@")[0].split(":")[-1] not in up.stdout, "the password masked"

    def site_status() -> dict:  # type: ignore[type-arg]
        shown = fleetbus(site, "site", "status", "--json")
        assert shown.returncode == 0, shown.stderr
        return json.loads(shown.stdout)

    def central_rows() -> dict:  # type: ignore[type-arg]
        shown = fleetbus(central, "sites", "--json")
        assert shown.returncode == 0, shown.stderr
        return {row["site"]: row for row in json.loads(shown.stdout)}

    wait_for(lambda: site_status()["uplink"]["state"] == "running", what="the uplink running")
    # the hazard states' shovel too: `sites add` made base2.hazards at central
    wait_for(lambda: site_status()["hazard_uplink"]["state"] == "running", what="the hazard uplink running")
    explorer = site.robot(site.add("explorer2", kind=RobotKind.EXPLORER))
    robots = json.loads(fleetbus(site, "site", "status", "--json").stdout)["not_forwarded"]
    assert robots == ["explorer2"], "a robot central did not send is shown, not forwarded"
    forward_robot(site.api, site.vhost, "explorer2")  # what `fleetbus site apply` does for central's robots
    assert site_status()["not_forwarded"] == []
    with central.worker(), site.worker():
        explorer.publish("status", status(80))
        # link_up is from central's management API, whose list of connections lags the shovels
        row = wait_for(
            lambda: (r := central_rows()["base2"])["forwarded"] == 1 and r["link_up"] and r,
            what="the event forwarded and the site's connection listed at central",
        )
        assert row["robots"] == ["explorer2"] and row["behind_s"] is not None

        pair.link.cut()
        wait_for(lambda: not central_rows()["base2"]["link_up"], what="central to see the link down")
        explorer.publish_many([("status", status(70)) for _ in range(5)])
        wait_for(lambda: site_status()["waiting"] == 5, what="five events waiting at the site")
        # the site's shovel notices the cut on its own: central seeing it says nothing of the site's view
        wait_for(lambda: site_status()["uplink"]["state"] != "running", what="the site's uplink not running")
        table = fleetbus(central, "sites")
        assert "base2" in table.stdout and "down" in table.stdout

    unknown = run(central, "sites", "robots", "base2", "--add", "nobody3")
    assert unknown.returncode == 2 and "not robots of the account registry: nobody3" in unknown.stderr
    central.add("explorer3", kind=RobotKind.EXPLORER)
    robots = run(central, "sites", "robots", "base2", "--add", "explorer3", "--remove", "explorer2")
    assert robots.returncode == 0, robots.stderr
    assert "told base2 to remove its copies of the accounts of explorer2" in robots.stdout
    assert (
        central.api.get_permissions(central.vhost, "base2")["write"]
        == "^((explorer3)\\.(events|beacon)|base2\\.(status|hazards))$"
    )


def test_site_up_refuses_a_central_url_its_shovels_could_not_verify(pair: SitePair) -> None:
    """An amqps:// URL naming central by its IP address gives the shovel no DNS name to check: it
    is refused, saying what to add, before any link changes."""
    unverifiable = pair.over_tls(pair.link.url("amqp://base1:secret@127.0.0.1/")).replace(
        "&server_name_indication=localhost", ""
    )
    url_file = pair.site.settings.data_dir / "unverifiable.url"
    save_secret(url_file, unverifiable)
    refused = fleetbus(pair.site, "site", "up", "--name", "base1", "--central-file", str(url_file))
    assert refused.returncode != 0
    assert "server_name_indication" in refused.stderr + refused.stdout
    assert "secret" not in refused.stderr + refused.stdout, "the password is never shown"
    assert pair.uplink_state() == "running", "the working link is left as it was"
