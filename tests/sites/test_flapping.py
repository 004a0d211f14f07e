"""A link to central that comes and goes every few seconds: nothing lost, nothing doubled, in order."""

from __future__ import annotations

import time
from collections import Counter

from fleetbus.schemas.routing import RobotKind
from tests.sites.pair import SitePair
from tests.support import Publishing, assert_stored_once_in_order, site_lane, wait_for

#: The link flaps for a minute, up and down in turn every few seconds.
FLAPPING_S = 60.0
PERIOD_S = 3.0


def test_a_flapping_link_loses_and_doubles_nothing(pair: SitePair) -> None:
    explorers = [pair.site.robot(pair.add_robot(f"explorer{i}", RobotKind.EXPLORER)) for i in (1, 2)]
    with pair.site.worker(), pair.central.worker():
        publishing = [Publishing(robot, period=0.05).start() for robot in explorers]
        ends = time.monotonic() + FLAPPING_S
        flaps = 0
        while time.monotonic() < ends:
            pair.link.cut()
            time.sleep(PERIOD_S)  # the outage itself: what the test injects, not a wait for a result
            pair.link.restore()
            flaps += 1
            time.sleep(PERIOD_S)
        sent = {p.robot.robot_id: p.stop() for p in publishing}
        total = sum(len(keys) for keys in sent.values())
        wait_for(lambda: pair.central.count() == total, timeout=120, what=f"all {total} at central")
        wait_for(lambda: pair.uplink_waiting() == 0, what="the uplink empty")
        # the site's worker stores its copies beside the uplink: its store may lag behind central's
        wait_for(
            lambda: all(pair.site_keys(robot) == Counter(keys) for robot, keys in sent.items()),
            what="each event once at the site",
        )
    assert flaps >= FLAPPING_S / (2 * PERIOD_S) - 1
    for robot, keys in sent.items():
        assert_stored_once_in_order(pair.central, robot, keys, site_lane)
        assert pair.site_keys(robot) == Counter(keys), f"{robot}: each once at the site"
    assert pair.central.dead_letters() == []
