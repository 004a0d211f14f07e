"""The team's newest map reaches the site: a map a robot at central made is fetched by a robot of
the site from its own site; the site's own maps are not sent back to it."""

from __future__ import annotations

from fleetbus.schemas.routing import DOWNLINK_QUEUE, RobotKind
from fleetbus.workers.downlink import apply_downlink
from tests.sites.pair import SitePair
from tests.support import wait_for
from tests.test_maps import TABLE2, pgm


def test_a_map_stored_at_central_is_fetched_by_a_site_robot_from_the_site(pair: SitePair) -> None:
    explorer = pair.central.robot(pair.central.add("explorer9", kind=RobotKind.EXPLORER))
    site_warden = pair.site.robot(pair.add_robot("warden3", RobotKind.WARDEN))
    image = pgm(300, 200)
    with pair.central.worker():
        explorer.publish_map(image, TABLE2)
        wait_for(
            lambda: pair.site.ready_messages(DOWNLINK_QUEUE) == 1,
            timeout=60,
            what="the map through the downlink",
        )
    assert apply_downlink(pair.site.settings, pair.site.admin_url, pair.site.api, idle_s=1.0) == 1
    with pair.site.worker():
        fetched = site_warden.fetch_map()
    assert fetched.pgm == image and fetched.robot_id == "explorer9"
    assert {k: fetched.metadata[k] for k in TABLE2} == TABLE2

    versions = pair.site.with_store(lambda repos: repos.maps.map_versions())
    assert [v.robot_id for v in versions] == ["explorer9"]
