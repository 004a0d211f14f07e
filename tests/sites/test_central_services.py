"""Central's own services with sites beside them: a site's wardens neither hold central's hazard
gate nor receive central's announcements, and what a site forwarded is stored, not announced."""

from __future__ import annotations

from fleetbus.schemas.routing import RobotKind, inbox_queue
from tests.factories import hazard
from tests.sites.pair import SitePair
from tests.support import notifications_until, wait_for
from tests.test_maps import TABLE2, pgm


def test_central_announces_its_own_hazards_only_and_never_to_a_sites_robots(pair: SitePair) -> None:
    central = pair.central
    site_explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER))
    site_warden = pair.site.robot(pair.add_robot("warden1", RobotKind.WARDEN))
    local_explorer = central.robot(central.add("explorer9", kind=RobotKind.EXPLORER))
    local_warden = central.robot(central.add("warden9", kind=RobotKind.WARDEN))
    robots = {r.name: r for r in central.with_store(lambda store: store.hazards.robots())}
    assert not robots["warden1"].in_service and robots["warden9"].in_service, "the site's warden is out"
    with pair.site.worker(), central.worker():
        site_warden.publish("localisation", {"localised": True})
        local_warden.publish("localisation", {"localised": True})
        forwarded = [site_explorer.publish("hazard", hazard(1, "at the site"))]
        forwarded += site_explorer.publish_map(pgm(300, 200), TABLE2)
        [announced] = site_warden.receive(1, timeout=30)
        assert announced.event == forwarded[0], "the site announced its hazard"
        wait_for(lambda: len(pair.forwards("explorer1")) == len(forwarded), what="all forwarded to central")
        sentinel = local_explorer.publish("hazard", hazard(2, "at central"))
        notes = notifications_until(local_warden, lambda note: note.event == sentinel)
        assert [note.event for note in notes if note.topic.value == "hazard"] == [sentinel], (
            "central announced its own hazard, not the site's"
        )
        assert central.ready_messages(inbox_queue("warden1")) == 0, "nothing for the site's warden at central"
        assert central.with_store(lambda store: store.maps.map_version()) is not None, "the site's map stored"
