"""The inboxes and the dead-letter queue are bounded by broker policies: when full they drop their
oldest messages, and every drop is counted in the store, against the real broker and both stores."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pika
import pytest

from fleetbus.broker.dead_letter_queue import peek_dead_letters
from fleetbus.broker.policies import SITE_DOWNLINK_PATTERN, SITE_MAPS_PATTERN
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import (
    DEAD_LETTER_QUEUE,
    OVERFLOW_QUEUE,
    RPC_QUEUE,
    RobotKind,
    commands_queue,
    inbox_queue,
)
from tests.factories import hazard
from tests.support import Bus, wait_for

LOCALISED = {"localised": True, "pose": {"x": 0.0, "y": 0.0}}


def overflow_counts(bus: Bus) -> dict[str, int]:
    counts = bus.with_store(lambda store: store.housekeeping.bound_counts())
    return {c.subject: c.count for c in counts if c.bound == "overflow"}


def bounded_by(bus: Bus, queue: str, policy: str) -> bool:
    """The broker applies ``policy`` to ``queue`` (the management API shows it within seconds)."""
    return bus.api.get_queue(bus.vhost, queue).get("policy") == policy


def in_inbox(bus: Bus, robot: str) -> list[Notification]:
    """What the robot's inbox holds now, as the broker keeps it (taken, not acked: it stays)."""
    with bus.admin_channel() as channel:
        held = []
        while (got := channel.basic_get(inbox_queue(robot)))[0] is not None:
            held.append(Notification.model_validate_json(got[2]))
        return held


def held(bus: Bus, queue: str) -> int:
    """Messages ready or unacked in ``queue``, as the management API reports them (seconds late)."""
    stats = bus.api.get_queue(bus.vhost, queue)
    return int(stats.get("messages_ready", 0)) + int(stats.get("messages_unacknowledged", 0))


def fleetbus(bus: Bus, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleetbus", *args],
        env=bus.worker_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )


# RabbitMQ 4 applies a policy to classic queues only when it carries no key of quorum queues
# (broker/policies.py): the bounds are checked on each release
@pytest.mark.rabbitmq_versions
def test_a_full_inbox_drops_its_oldest_notifications_counts_them_and_the_warden_resyncs(
    stored_bus: Bus,
) -> None:
    bus = stored_bus
    bus.settings = bus.settings.updated(inbox_max=("3",))
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    bus.service_accounts()  # `fleetbus setup`: the policies
    wait_for(lambda: bounded_by(bus, inbox_queue("warden1"), "fleetbus-inboxes"), what="the inbox policy")
    with bus.worker():
        warden.publish("localisation", LOCALISED)
        for i in range(5):
            explorer.publish("hazard", hazard(i))
        wait_for(lambda: overflow_counts(bus).get("warden1.inbox maxlen") == 2, what="two drops counted")
        assert [note.hazard_id for note in in_inbox(bus, "warden1")] == [3, 4, 5], "the newest three stay"
        # the warden's client rebuilds what its inbox lost (hazard.open) and hands out every hazard
        notes = warden.receive(5, timeout=30)
        assert sorted(note.hazard_id for note in notes) == [1, 2, 3, 4, 5]
    shown = fleetbus(bus, "stats", "--json")
    assert shown.returncode == 0, shown.stderr
    bounds = [json.loads(line) for line in shown.stdout.splitlines() if '"bound"' in line]
    assert {"bound": "overflow", "subject": "warden1.inbox maxlen", "count": 2} in [
        {k: b[k] for k in ("bound", "subject", "count")} for b in bounds
    ]


def test_a_full_dead_letter_queue_keeps_the_newest_refusals_and_counts_the_dropped(stored_bus: Bus) -> None:
    bus = stored_bus
    bus.settings = bus.settings.updated(dead_letters_max=("3",))
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.service_accounts()
    wait_for(
        lambda: bounded_by(bus, DEAD_LETTER_QUEUE, "fleetbus-dead-letters"), what="the dead-letter policy"
    )
    with bus.worker() as worker:
        for n in range(5):
            bus.publish_raw(account, "explorer1.hazard", b"not json %d" % n, message_id=f"bad-{n}")
        wait_for(lambda: worker.stats().rejected == 5, what="five refused")
        wait_for(
            lambda: overflow_counts(bus).get("fleetbus.dead-letters maxlen") == 2, what="two drops counted"
        )
    assert [letter.message_id for letter in peek_dead_letters(bus.admin_url)] == ["bad-2", "bad-3", "bad-4"]
    listed = fleetbus(bus, "dlq")
    assert listed.returncode == 0, listed.stderr
    assert "3 dead letters" in listed.stdout and "2 older ones were dropped" in listed.stdout
    # a listing cut short says how many there are, and the stats count the queue, not the listing
    shorter = fleetbus(bus, "dlq", "--limit", "2")
    assert "3 dead letters, the oldest 2 listed" in " ".join(shorter.stdout.split()), shorter.stdout


def test_a_notification_the_client_cannot_read_is_set_aside_and_counted(stored_bus: Bus) -> None:
    """A note this client cannot read (a newer server's, say) is rejected, not acked and lost: the
    inbox's dead-letter exchange has the workers count it, and the next one is handed out."""
    bus = stored_bus
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    bus.service_accounts()  # `fleetbus setup`: the policies
    wait_for(lambda: bounded_by(bus, inbox_queue("warden1"), "fleetbus-inboxes"), what="the inbox policy")
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        channel.basic_publish("", inbox_queue("warden1"), b'{"topic": "hazard", "new_field": 1}')
    with bus.worker():
        warden.publish("localisation", LOCALISED)
        # its client reads the inbox: the note it cannot read is not handed out, but set aside
        assert list(warden.notifications(timeout=2)) == []
        wait_for(lambda: overflow_counts(bus).get("warden1.inbox rejected") == 1, what="it counted")
        sent = explorer.publish("hazard", hazard(0))  # and the next one is handed out
        [note] = warden.receive(1, timeout=30)
        assert note.event == sent


@pytest.mark.rabbitmq_versions  # a policy for each queue type on RabbitMQ 4, one for both on 3
def test_a_command_or_a_request_that_expires_unread_is_counted(stored_bus: Bus) -> None:
    """Commands live 30 s, a request until its caller gives up: what expired unread (the robot away,
    the workers behind) is counted with the dropped messages, on a classic queue too."""
    bus = stored_bus
    bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.service_accounts()  # `fleetbus setup`: the policies (a queue has its policy once it is set)
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        for queue in (commands_queue("explorer1"), RPC_QUEUE):  # no worker consuming yet
            channel.basic_publish("", queue, b"{}", pika.BasicProperties(expiration="1"))
    with bus.worker():
        wait_for(
            lambda: (
                {k: v for k, v in overflow_counts(bus).items() if k.endswith("expired")}
                == {"explorer1.commands expired": 1, "fleetbus.rpc.requests expired": 1}
            ),
            what="both counted",
        )


def test_a_dropped_message_with_an_x_death_not_the_brokers_is_counted_unreadable_and_counting_goes_on(
    bus: Bus,
) -> None:
    """Anyone who may publish to the overflow queue can send any ``x-death``: one that is not a
    list of tables is counted as unreadable and acked. It used to end the counting for good, its
    consumer left on the queue holding what came next unacked."""
    bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.service_accounts()  # `fleetbus setup`: the policies (a queue has its policy once it is set)
    with bus.worker():
        with bus.admin_channel() as channel:
            channel.confirm_delivery()
            bad = pika.BasicProperties(headers={"x-death": "not the broker's"})
            channel.basic_publish("", OVERFLOW_QUEUE, b"{}", bad)
        wait_for(lambda: bus.ready_messages(OVERFLOW_QUEUE) == 0, what="the malformed one taken")
        with bus.admin_channel() as channel:  # a real drop: a command that expires unread
            channel.confirm_delivery()
            channel.basic_publish(
                "", commands_queue("explorer1"), b"{}", pika.BasicProperties(expiration="1")
            )
        wait_for(
            lambda: overflow_counts(bus).get("explorer1.commands expired") == 1, what="the real drop counted"
        )
        wait_for(lambda: not held(bus, OVERFLOW_QUEUE), what="both acked")
    assert overflow_counts(bus) == {"unreadable": 1, "explorer1.commands expired": 1}


def test_the_policies_of_the_sites_downlinks_match_central_queues_of_sites_only() -> None:
    """A site runs `fleetbus setup` too: its own downlink queues must keep their own bounds."""
    queues = ("base1.downlink", "base1.downlink.maps", "fleetbus.downlink", "fleetbus.downlink.rejected")
    assert [q for q in queues if re.search(SITE_DOWNLINK_PATTERN, q)] == ["base1.downlink"]
    assert [q for q in queues if re.search(SITE_MAPS_PATTERN, q)] == ["base1.downlink.maps"]
