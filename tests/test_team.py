"""The hazard gate follows the team, against the real broker and both stores: a removed warden or
one out of service no longer holds hazards; with no warden they wait for the first to join and
localise; an announcement no warden's inbox took stays held and says why; a warden put back in
service gets what it missed, and a warden's client rebuilds its list of open hazards on start and
after every reconnect."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any
from urllib.parse import urlsplit

import pytest

from fleetbus.broker.accounts import Role
from fleetbus.broker.topology import account_topology, declare_with_url
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RobotKind, inbox_queue
from fleetbus.workers.store.hazards import CLAIM_WHILE_OPEN
from tests.factories import hazard
from tests.link import NetworkLink
from tests.support import Bus, notifications_until, read_inbox, wait_for
from tests.test_cli import fleetbus

WARDEN, EXPLORER = RobotKind.WARDEN, RobotKind.EXPLORER


def states(bus: Bus) -> list[str]:
    """Each open hazard's state, in id order."""
    return [h.state.value for h in bus.with_store(lambda store: store.hazards.open_hazards("default"))]


def held_because(bus: Bus) -> list[str | None]:
    """What ``fleetbus hazards`` says each open hazard waits for."""
    listed = fleetbus(bus, "hazards", "--json")
    assert listed.returncode == 0, listed.stderr
    return [json.loads(line)["held_because"] for line in listed.stdout.splitlines()]


def handled(bus: Bus, robot: str, localised: bool) -> bool:
    """Whether the hazard service recorded ``robot``'s latest localisation: every express event it
    published before that one has been handled too (one queue, one consumer, in order)."""
    return any(
        r.name == robot and r.localised is localised for r in bus.with_store(lambda s: s.hazards.robots())
    )


def team(bus: Bus) -> dict[str, Any]:
    listed = fleetbus(bus, "team", "--json")
    assert listed.returncode == 0, listed.stderr
    return json.loads(listed.stdout)


def inbox_admin(bus: Bus, action: str, robot: str) -> None:
    """``queue_purge`` or ``queue_delete`` a robot's inbox as the administrator: its inbox lost."""
    connection = blocking_connection(bus.admin_url)
    try:
        getattr(connection.channel(), action)(inbox_queue(robot))
    finally:
        connection.close()


def test_removing_a_warden_that_never_localised_releases_the_held_hazards(stored_bus: Bus) -> None:
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    warden1 = bus.robot(bus.add("warden1", kind=WARDEN))
    bus.add("warden2", kind=WARDEN)  # never connects: a robot lost before the mission started
    with bus.worker():
        warden1.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(0)), ("hazard", hazard(1, "Gas leak"))])
        explorer.publish("localisation", {"localised": True})  # after the hazards, on the same lane
        wait_for(lambda: handled(bus, "explorer1", True), what="the hazards handled")
        assert states(bus) == ["held", "held"]
        assert held_because(bus) == ["waiting for warden2: not localised, last seen never"] * 2

        removed = fleetbus(bus, "users", "remove", "warden2")
        assert removed.returncode == 0, removed.stderr
        assert "took it out of the team" in removed.stdout
        notes = warden1.receive(2, timeout=30)
        assert [n.hazard_id for n in notes] == [1, 2] and [n.event for n in notes] == sent
        wait_for(lambda: states(bus) == ["announced", "announced"], what="both marked announced")
    assert [r.name for r in bus.with_store(lambda store: store.hazards.robots(WARDEN.value))] == ["warden1"]


def test_with_no_warden_hazards_wait_for_the_first_to_join_and_localise(stored_bus: Bus) -> None:
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    operator = bus.robot(bus.add("ops1", role=Role.OPERATOR))
    with bus.worker():
        sent = explorer.publish_many([("hazard", hazard(n)) for n in range(3)])
        explorer.publish("localisation", {"localised": True})
        wait_for(lambda: handled(bus, "explorer1", True), what="the hazards handled")
        assert states(bus) == ["held"] * 3, "not announced to nobody"
        assert held_because(bus) == ["no warden in the team"] * 3
        assert bus.ready_messages("ops1.inbox") == 0, "not even to the operators"

        warden = bus.robot(bus.add("warden1", kind=WARDEN))
        assert held_because(bus) == ["waiting for warden1: not localised, last seen never"] * 3
        warden.publish("localisation", {"localised": True})
        notes = warden.receive(3, timeout=30)
        assert [n.hazard_id for n in notes] == [1, 2, 3] and [n.event for n in notes] == sent
        assert [n.hazard_id for n in operator.receive(3, timeout=30)] == [1, 2, 3]
    assert states(bus) == ["announced"] * 3


def test_a_warden_out_of_service_neither_holds_nor_receives_and_catches_up_when_back(
    stored_bus: Bus,
) -> None:
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    warden1 = bus.robot(bus.add("warden1", kind=WARDEN))
    warden2 = bus.robot(bus.add("warden2", kind=WARDEN))
    with bus.worker():
        warden1.publish("localisation", {"localised": True})
        first = explorer.publish("hazard", hazard(0))
        explorer.publish("localisation", {"localised": True})
        wait_for(lambda: handled(bus, "explorer1", True), what="the hazard handled")
        assert states(bus) == ["held"], "warden2 is not localised"

        out = fleetbus(bus, "team", "out", "warden2", "--by", "ops1")
        assert out.returncode == 0, out.stderr
        [note] = warden1.receive(1, timeout=30)
        assert note.event == first and note.hazard_state == "announced"
        second = explorer.publish("hazard", hazard(1))
        assert [n.event for n in warden1.receive(1, timeout=30)] == [second]
        wait_for(lambda: states(bus) == ["announced"] * 2, what="both marked announced")
        assert bus.ready_messages(inbox_queue("warden2")) == 0, "out of service: sent nothing"
        listed = {robot["name"]: robot for robot in team(bus)["robots"]}
        assert (listed["warden2"]["in_service"], listed["warden2"]["counts_for_gate"]) == (False, False)
        assert listed["warden2"]["service_changed_by"] == "ops1" and listed["warden2"]["service_changed_at"]
        assert team(bus)["gate"] == {"open": True, "announces_to": ["warden1"], "closed_because": None}

        back = fleetbus(bus, "team", "in", "warden2", "--by", "ops2")
        assert back.returncode == 0, back.stderr
        third = explorer.publish("hazard", hazard(2))
        explorer.publish("localisation", {"localised": False})
        wait_for(lambda: handled(bus, "explorer1", False), what="the third hazard handled")
        assert states(bus) == ["announced", "announced", "held"], "back in service, warden2 holds the gate"
        warden2.publish("localisation", {"localised": True})
        assert [n.event for n in warden1.receive(1, timeout=30)] == [third]
        # warden2's inbox itself (its client, never started, would rebuild and skip repeats): the
        # express lane sent it what it missed on the team change, then the third, on one channel
        assert inbox_until(bus, "warden2", third.message_id) == [
            (1, "announced"),
            (2, "announced"),
            (3, "announced"),
        ], "what it missed, once, in order, before anything newer"
        # the sentinel: a repeat of the catch-up or of an announcement would be sent by the same
        # lane before the next hazard's announcement, on the same channel to the same inbox
        fourth = explorer.publish("hazard", hazard(3))
        assert inbox_until(bus, "warden2", fourth.message_id) == [(4, "announced")], "nothing twice"
    listed = {robot["name"]: robot for robot in team(bus)["robots"]}
    assert (listed["warden2"]["in_service"], listed["warden2"]["service_changed_by"]) == (True, "ops2")


def test_an_announcement_no_wardens_inbox_took_stays_held_and_says_why(stored_bus: Bus) -> None:
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: handled(bus, "warden1", True), what="warden1 localised")
        inbox_admin(bus, "queue_delete", "warden1")  # its inbox gone: nobody would hear the hazard
        sent = explorer.publish("hazard", hazard(0))
        wait_for(
            lambda: (held_because(bus)[0] or "").startswith("the announcement at"), what="the reason stored"
        )
        [why] = held_because(bus)
        assert "reached no warden" in why and "no inbox for warden1" in why, why
        assert states(bus) == ["held"]

        asyncio.run(declare_with_url(bus.admin_url, [account_topology("warden1", kind=WARDEN)]))
        warden.publish("localisation", {"localised": True})  # the gate is looked at again
        [note] = warden.receive(1, timeout=30)
        assert note.event == sent and note.hazard_id == 1
        wait_for(lambda: states(bus) == ["announced"], what="marked announced")
    assert held_because(bus) == [None]


def inbox_until(
    bus: Bus, robot: str, sentinel: str, timeout: float = 30
) -> list[tuple[int | None, str | None]]:
    """(hazard id, state) of each notification in ``robot``'s inbox, read as it arrives up to the
    one announcing event ``sentinel``: the inbox itself, without the client's rebuild on start."""
    notes = read_inbox(bus.admin_url, robot, lambda got: got[-1].event.message_id == sentinel, timeout)
    seen = [(note.hazard_id, note.hazard_state) for note in notes]
    assert notes and notes[-1].event.message_id == sentinel, f"{robot}: nothing for {timeout} s after {seen}"
    return seen


def test_a_hazard_claimed_before_its_announcement_was_marked_still_reaches_every_warden(
    stored_bus: Bus,
) -> None:
    """A worker that dies between one warden's copy and the mark leaves a hazard that warden may
    already have claimed: the next announces it again, claimed, so that the other wardens' inboxes
    get it too (a warden already running rebuilds nothing: it has not reconnected)."""
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    wardens = [bus.robot(bus.add(name, kind=WARDEN)) for name in ("warden1", "warden2")]
    with bus.worker():
        wardens[0].publish("localisation", {"localised": True})
        explorer.publish("hazard", hazard(0))
        explorer.publish("localisation", {"localised": True})
        wait_for(lambda: handled(bus, "explorer1", True), what="the hazard registered, held for warden2")
    # what a worker killed after warden1's copy left: warden1 claimed, the mark never came
    bus.with_store(
        lambda store: store.hazards.apply_transition(
            "default", 1, "warden1", CLAIM_WHILE_OPEN, datetime.now(timezone.utc)
        )
    )
    assert states(bus) == ["claimed"]
    with bus.worker():
        wardens[1].publish("localisation", {"localised": True})
        later = explorer.publish("hazard", hazard(1))
        assert [inbox_until(bus, name, later.message_id) for name in ("warden1", "warden2")] == [
            [(1, "claimed"), (2, "announced")],
            [(1, "claimed"), (2, "announced")],
        ], "hazard 1 announced again once, claimed, before the next"
    assert states(bus) == ["claimed", "announced"]
    assert bus.with_store(lambda store: store.hazards.unannounced_hazards()) == []


@pytest.fixture
def link(bus: Bus) -> Iterator[NetworkLink]:
    network = NetworkLink(urlsplit(bus.admin_url).port or 5672).start()
    yield network
    network.stop()


def test_a_warden_rebuilds_its_open_hazards_on_start_and_after_every_reconnect(
    bus: Bus, link: NetworkLink
) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    warden1 = bus.robot(bus.add("warden1", kind=WARDEN), via=link)
    warden2 = bus.robot(bus.add("warden2", kind=WARDEN))
    with bus.worker():
        warden1.publish("localisation", {"localised": True})
        warden2.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(n)) for n in range(3)])
        assert [n.hazard_id for n in warden2.receive(3, timeout=30)] == [1, 2, 3]
        warden2.claim_hazard(2)
        wait_for(lambda: states(bus) == ["announced", "claimed", "announced"], what="hazard 2 claimed")
        inbox_admin(bus, "queue_purge", "warden1")  # warden1's inbox lost before its program listens

        rebuilt = warden1.receive(2, timeout=30)  # not hazard 2: warden2 holds it
        assert [(n.event, n.hazard_state) for n in rebuilt] == [
            (sent[0], "announced"),
            (sent[2], "announced"),
        ]
        # the sentinel: announced after the rebuild, it comes after whatever the client has left
        # to hand out (the rest of the rebuild, then the inbox, in order)
        sentinel = explorer.publish("hazard", hazard(3))
        after = notifications_until(warden1, lambda note: note.event == sentinel)
        assert [n.event for n in after] == [sentinel], "no hazard twice, none another warden holds"

        link.cut()  # warden1 away: the next hazard reaches its inbox, which is then lost again
        fifth = explorer.publish("hazard", hazard(4))
        wait_for(lambda: states(bus) == ["announced", "claimed", *["announced"] * 3], what="hazard 5 sent")
        inbox_admin(bus, "queue_purge", "warden1")
        link.restore()
        [missed] = warden1.receive(1, timeout=60)  # it reconnects and rebuilds its list
        assert (missed.event, missed.hazard_id, missed.hazard_state) == (fifth, 5, "announced")
        sixth = explorer.publish("hazard", hazard(5))  # the sentinel, after the rebuild again
        after = notifications_until(warden1, lambda note: note.event == sixth)
        assert [n.event for n in after] == [sixth], "none of the earlier ones again"


def test_the_cli_claims_for_a_warden_and_refuses_a_step_the_rules_do_not_allow(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=WARDEN))
    with bus.worker():
        warden.publish("localisation", {"localised": True})
        wait_for(lambda: handled(bus, "warden1", True), what="warden1 localised")
        sent = explorer.publish("hazard", hazard(0))
        assert [n.event for n in warden.receive(1, timeout=30)] == [sent]
        early = fleetbus(bus, "hazards", "reached", "1", "--for", "warden1")
        assert (early.returncode, early.stderr) == (
            1,
            "error: hazard 1 is announced; warden1 cannot have it reached\n",
        )
        claimed = fleetbus(bus, "hazards", "claim", "1", "--for", "warden1", "--by", "ops1")
        assert claimed.returncode == 0, claimed.stderr
        assert "hazard 1: claimed for warden1 (by ops1)" in claimed.stdout
        [note] = warden.receive(1, timeout=30)
        assert (note.hazard_state, note.claimed_by) == ("claimed", "warden1")
        # released by an operator: the warden is told it is announced again, as it was at first,
        # and its client hands that out, not taking it for the first announcement's copy
        released = fleetbus(bus, "hazards", "release", "1", "--for", "warden1", "--by", "ops1")
        assert released.returncode == 0, released.stderr
        [note] = warden.receive(1, timeout=30)
        assert (note.event, note.hazard_state, note.claimed_by) == (sent, "announced", None)
        claimed = fleetbus(bus, "hazards", "claim", "1", "--for", "warden1", "--by", "ops1")
        assert claimed.returncode == 0, claimed.stderr
        [note] = warden.receive(1, timeout=30)
        assert (note.hazard_state, note.claimed_by) == ("claimed", "warden1"), "claimed again: news too"
    assert states(bus) == ["claimed"]
