"""A broker killed with SIGKILL while the uplink forwards: central still ends with every event once.

The shovel acks a message on the site only once central confirmed it (``on-confirm``), so a kill
of either node loses nothing; what was in flight is forwarded again and recognised by central's
store as a duplicate, not stored twice.
"""

from __future__ import annotations

from collections import Counter

import pytest

from fleetbus.schemas.routing import RobotKind
from tests.factories import status
from tests.sites.pair import SitePair
from tests.support import assert_stored_once_in_order, wait_for

EVENTS = 3000
#: What the site's links send central before the link stalls: a few hundred of the events.
STALL_AFTER_BYTES = 400_000


def backlog(pair: SitePair) -> list[tuple[str, int]]:
    """``EVENTS`` events published at the site with the link cut, waiting in the uplink."""
    explorer = pair.site.robot(pair.add_robot("explorer1", RobotKind.EXPLORER), connect_timeout=60)
    pair.link.cut()
    events = explorer.publish_many([("status", status(80)) for _ in range(EVENTS)])
    wait_for(lambda: pair.uplink_waiting() == EVENTS, timeout=60, what="the backlog in the uplink")
    return [(event.epoch, event.seq) for event in events]


@pytest.mark.parametrize("victim", ["central", "site"])
def test_a_node_killed_mid_forward_loses_and_doubles_nothing(pair: SitePair, victim: str) -> None:
    node = pair.central_node if victim == "central" else pair.site_node
    with pair.site.worker(), pair.central.worker():
        sent = backlog(pair)
        # the link to central stops moving part way through the backlog: the kill comes mid-forward
        pair.link.stall_after(STALL_AFTER_BYTES)
        pair.link.restore()
        wait_for(lambda: pair.link.stalled, what="the uplink forwarding, then stalled")
        assert 0 < pair.uplink_waiting() < EVENTS, "killed while forwarding (the backlog not yet through)"
        node.kill()
        pair.link.resume()
        node.up()
        wait_for(lambda: pair.central.count() == EVENTS, timeout=180, what=f"all {EVENTS} at central")
        wait_for(lambda: pair.uplink_waiting() == 0, timeout=60, what="the uplink empty")
        wait_for(lambda: len(pair.forwards()) == EVENTS, what="every forward recorded")
        # the site's worker stores its copies beside the uplink: its store may lag behind central's
        wait_for(lambda: pair.site_keys("explorer1") == Counter(sent), what="each event once at the site")
    assert pair.central_keys("explorer1") == Counter(sent), "each once at central"
    assert pair.site_keys("explorer1") == Counter(sent), "each once at the site"
    assert_stored_once_in_order(pair.central, "explorer1", sent)
    assert pair.central.dead_letters() == []
