"""Several worker processes sharing the ingest shards, on the real broker and both stores.

Every event stored exactly once and in its robot's order, the hazard gate and the FIFO
announcements correct with the wardens and the explorers on different workers, one battery
warning per crossing, and a worker killed with SIGKILL while the others run.
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from fleetbus.broker.accounts import Account, Role
from fleetbus.broker.shards import read_shard_map
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.errors import BrokerUnavailable
from fleetbus.publishers.rpc import ServiceRefused, ServiceTimeout
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import RobotKind, Topic, inbox_queue
from fleetbus.workers.runner import EXPRESS_PREFETCH
from fleetbus.workers.shards import shard_lease, share
from fleetbus.workers.store.hazards import HazardState
from tests.factories import hazard, status
from tests.support import (
    Bus,
    EventKey,
    Publishing,
    assert_stored_once_in_order,
    keys,
    notifications_until,
    read_inbox,
    wait_for,
)

SHARDS = 4


@contextmanager
def worker_processes(bus: Bus, count: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``count`` worker processes (no recorder), started at once; returns once each holds its share."""
    workers = [bus.spawn_worker("--no-recorder") for _ in range(count)]
    try:
        expected = sorted(share(SHARDS, [str(n) for n in range(count)], str(n)) for n in range(count))

        def shares_taken() -> bool:
            ended = [worker.returncode for worker in workers if worker.poll() is not None]
            assert not ended, f"a worker started at the same time as others ended: exit {ended}"
            return sorted(bus.shard_holders().values()) == expected

        wait_for(shares_taken, timeout=90, what=f"{expected} shards each")
        yield workers
    finally:
        for worker in workers:
            if worker.poll() is None:
                worker.terminate()
        for worker in workers:
            assert worker.wait(60) in (0, -9), "SIGTERM stops a worker cleanly"


def hazard_states(bus: Bus) -> Counter[HazardState]:
    return Counter(h.state for h in bus.with_store(lambda store: store.hazards.open_hazards("default")))


def in_parallel(*jobs: threading.Thread) -> None:
    for job in jobs:
        job.start()
    for job in jobs:
        job.join(120)
        assert not job.is_alive()


def publisher(robot: RobotClient, items: list, sent: list[EventKey]) -> threading.Thread:
    def publish() -> None:
        for start in range(0, len(items), 10):  # in windows, as robot code does, to interleave robots
            sent.extend(keys(robot.publish_many(items[start : start + 10])))

    return threading.Thread(target=publish)


def battery_run(levels: list[float]) -> list:
    return [("status", status(level)) for level in levels]


LOW = 20.0
#: A battery that crosses below 20 % three times (a warning each), and stays low in between.
SWINGS = [60.0, 40.0, 25.0, 19.0, 15.0, 10.0, 30.0, 50.0, 15.0] * 3


def crossings(levels: list[float]) -> int:
    return sum(1 for n, level in enumerate(levels) if level < LOW and (n == 0 or levels[n - 1] >= LOW))


@pytest.mark.parametrize(
    ("workers", "store"),
    [(2, "sqlite"), (4, "sqlite"), (2, "mongodb")],
    ids=["2-workers-sqlite", "4-workers-sqlite", "2-workers-mongodb"],
)
def test_worker_processes_store_everything_once_in_order_and_announce_hazards_once_in_fifo_order(
    bus: Bus, workers: int, store: str, request: pytest.FixtureRequest
) -> None:
    if store == "mongodb":
        url: str = request.getfixturevalue("mongodb_url")
        bus.settings = bus.settings.updated(
            mongodb_url=f"{url.rstrip('/')}/scale_{bus.vhost.replace('-', '_')}"
        )
    bus.settings = bus.settings.updated(ingest_shards=SHARDS)
    team = [
        ("explorer1", RobotKind.EXPLORER),
        ("warden1", RobotKind.WARDEN),
        ("explorer2", RobotKind.EXPLORER),
        ("warden2", RobotKind.WARDEN),
        ("guide1", RobotKind.GUIDE),
    ]
    accounts = {name: bus.add(name, kind=kind) for name, kind in team}
    robots = {name: bus.robot(account) for name, account in accounts.items()}
    ops = bus.robot(bus.add("ops1", role=Role.OPERATOR))
    shard_map = read_shard_map(bus.api, bus.vhost, SHARDS)
    assert {name: shard_map.shard_of(name) for name, _ in team} == {
        "explorer1": 0,
        "warden1": 1,
        "explorer2": 2,
        "warden2": 3,
        "guide1": 0,
    }, "the gate's inputs and the hazards it holds go through different shards"
    sent: dict[str, list[EventKey]] = {name: [] for name in robots}

    with worker_processes(bus, workers):
        # held: no warden is localised yet; the explorers' hazards wait in the store
        in_parallel(
            *(
                publisher(
                    robots[name],
                    [("hazard", hazard(n)) for n in range(8)] + battery_run([90] * 12),
                    sent[name],
                )
                for name in ("explorer1", "explorer2")
            )
        )
        wait_for(lambda: hazard_states(bus) == {HazardState.HELD: 16}, what="16 hazards held")
        sent["warden1"] += keys([robots["warden1"].publish("localisation", {"localised": True})])
        wait_for(
            lambda: {r.name: r.localised for r in bus.with_store(lambda s: s.hazards.robots("warden"))}[
                "warden1"
            ],
            what="warden1 recorded as localised",
        )
        # a sentinel behind it on the express lane (one consumer, in order): once it is recorded, the
        # batch with warden1's localisation was handled, and any hazard the gate let go is in an inbox
        sent["explorer1"] += keys([robots["explorer1"].publish("localisation", {"localised": True})])
        wait_for(
            lambda: {r.name: r.localised for r in bus.with_store(lambda s: s.hazards.robots())}["explorer1"],
            what="the sentinel recorded",
        )
        assert [bus.ready_messages(inbox_queue(w)) for w in ("warden1", "warden2")] == [0, 0]
        assert hazard_states(bus) == {HazardState.HELD: 16}, "one warden localised: still held"

        # the last warden localises on another worker while both explorers go on detecting
        in_parallel(
            publisher(
                robots["warden2"],
                [("localisation", {"localised": True}), *battery_run([80] * 30)],
                sent["warden2"],
            ),
            *(
                publisher(
                    robots[name],
                    [item for n in range(8, 28) for item in (("hazard", hazard(n)), ("status", status(90)))],
                    sent[name],
                )
                for name in ("explorer1", "explorer2")
            ),
            # each battery crosses below 20 % once: one warning each
            *(publisher(robots[name], battery_run(SWINGS), sent[name]) for name in ("warden1", "guide1")),
        )
        notes = {name: inbox(accounts[name], 56, timeout=60) for name in ("warden1", "warden2")}
        # a sentinel hazard after the rest: the next thing in each warden's inbox (FIFO)
        sentinel = robots["explorer1"].publish("hazard", hazard(99))
        sent["explorer1"] += keys([sentinel])
        for name in notes:
            assert [n.event for n in inbox(accounts[name], 1, timeout=60)] == [sentinel], (
                "no hazard announced twice"
            )
        # each battery crosses below 20 % once more after everything it sent: its last warning
        last_lows = {}
        for name in ("warden1", "guide1"):
            raised, low = robots[name].publish_many(battery_run([90.0, 5.0]))
            sent[name] += keys([raised, low])
            last_lows[name] = low
        warnings: list[Notification] = []
        for low in last_lows.values():  # each robot's warnings come in order (its shard's)
            if low not in {n.event for n in warnings}:
                warnings += notifications_until(ops, lambda note, low=low: note.event == low, timeout=60)
        for name in robots:
            wait_for(
                lambda name=name: bus.count(robot_id=name) == len(sent[name]), what=f"{name}'s events stored"
            )

    hazards = {h.hazard_id: h for h in bus.with_store(lambda store: store.hazards.open_hazards("default"))}
    assert len(hazards) == 57 and all(h.state is HazardState.ANNOUNCED for h in hazards.values())
    for warden, received in notes.items():
        ids = [note.hazard_id for note in received]
        assert ids == sorted(hazards)[:56], f"{warden}: every hazard once, in the order registered (FIFO)"
        for explorer in ("explorer1", "explorer2"):
            seqs = [note.event.seq for note in received if note.event.robot_id == explorer]
            assert seqs == sorted(seqs) and len(seqs) == 28, (
                f"{warden}: {explorer}'s hazards in detection order"
            )
        first_16 = {(n.event.robot_id, n.event.epoch, n.event.seq) for n in received[:16]}
        assert first_16 == {(h.robot_id, h.epoch, h.seq) for h in hazards.values() if h.hazard_id <= 16}, (
            "held ones first"
        )
    battery = Counter(n.event.robot_id for n in warnings if n.topic is Topic.BATTERY)
    assert battery == {"warden1": crossings(SWINGS) + 1, "guide1": crossings(SWINGS) + 1}, (
        "one per crossing below 20 % (the last one each robot's sentinel)"
    )
    for name in robots:
        assert_stored_once_in_order(bus, name, sent[name])
    assert bus.gaps() == [] and bus.with_store(lambda store: store.events.duplicates()) == []


def _hazard_ids(notes: list[Notification]) -> list[int | None]:
    return [note.hazard_id for note in notes]


def inbox(account: Account, count: int, timeout: float) -> list[Notification]:
    """The first ``count`` notifications the broker delivered to the account's inbox, repeats
    included (fewer when nothing more comes for ``timeout`` s)."""
    return read_inbox(account.amqp_url, account.name, lambda notes: len(notes) == count, timeout)


def test_a_worker_killed_while_others_run_loses_and_doubles_nothing(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=SHARDS)
    names = ["robot1", "robot2", "robot3", "robot4"]
    robots = [bus.robot(bus.add(name, kind=RobotKind.EXPLORER)) for name in names]
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with worker_processes(bus, 2) as (victim, survivor):
        warden.publish("localisation", {"localised": True})
        streams = [Publishing(robot, period=0.005, hazard_every=10).start() for robot in robots]
        wait_for(lambda: bus.count() >= 400, timeout=60, what="400 events stored")
        victim.kill()
        killed_at = time.monotonic()
        assert victim.wait(10) == -9
        wait_for(
            lambda: list(bus.shard_holders().values()) == [SHARDS],
            timeout=30,
            what="the survivor holding every shard",
        )
        takeover = time.monotonic() - killed_at
        stored_at_takeover = bus.count()
        wait_for(
            lambda: bus.count() >= stored_at_takeover + 100, timeout=60, what="the survivor storing more"
        )
        sent = [stream.stop() for stream in streams]
        for name, seqs in zip(names, sent, strict=True):
            wait_for(
                lambda name=name, seqs=seqs: bus.count(robot_id=name) >= len(seqs), timeout=60, what=f"{name}"
            )
        hazards = sum(1 for seqs in sent for n in range(len(seqs)) if n % 10 == 0)
        received = warden.receive(hazards, timeout=60)
        sentinel = robots[0].publish("hazard", hazard(10_000))
        after = notifications_until(warden, lambda note: note.event == sentinel, timeout=60)
        assert [n.event for n in after] == [sentinel], "nothing announced twice"
        sent[0] = [*sent[0], *keys([sentinel])]
        assert survivor.poll() is None
    assert takeover < 10, f"the dead worker's shards were taken over in {takeover:.1f} s"
    for name, seqs in zip(names, sent, strict=True):
        assert_stored_once_in_order(bus, name, seqs)
    assert bus.gaps() == []
    ids = _hazard_ids(received)
    assert ids == sorted(set(ids)) and len(ids) == hazards, "every hazard announced, once each, in order"


class ClaimingWarden(threading.Thread):
    """A warden that claims every hazard the moment its inbox hands it over, as the other does: for
    each hazard, two claims race through whichever workers answer requests.

    It reads its inbox itself (every copy the broker delivered, repeats included, with the time
    each arrived) and claims through its robot client, again after a claim lost to a worker's death.
    It stops once it has had ``expected`` hazards (set when the explorers have stopped).
    """

    def __init__(self, account: Account, robot: RobotClient) -> None:
        super().__init__(name=f"claiming-{account.name}", daemon=True)
        self.account, self.robot = account, robot
        self.expected: int | None = None
        self.copies: list[tuple[int, float]] = []
        """Every hazard id delivered to its inbox, with ``time.monotonic()`` at arrival."""
        self.won: set[int] = set()
        self.lost: set[int] = set()
        self.error: BaseException | None = None

    def first_seen(self) -> list[int]:
        """Hazard ids in the order they first arrived: what its program is handed."""
        return list(dict.fromkeys(hazard_id for hazard_id, _ in self.copies))

    def run(self) -> None:
        try:
            connection = blocking_connection(self.account.amqp_url)
            channel = connection.channel()
            channel.basic_qos(prefetch_count=64)
            inbox = channel.consume(inbox_queue(self.account.name), inactivity_timeout=1)
            last = time.monotonic()
            while self.expected is None or len(self.won | self.lost) < self.expected:
                method, _, body = next(inbox)
                if method is None:
                    assert time.monotonic() - last < 120, f"{self.account.name}: nothing for 120 s"
                    continue
                last = time.monotonic()
                hazard_id = Notification.model_validate_json(body).hazard_id
                assert hazard_id is not None
                self.copies.append((hazard_id, last))
                if hazard_id not in self.won | self.lost:
                    self._claim(hazard_id)
                channel.basic_ack(method.delivery_tag)
            connection.close()
        except BaseException as error:  # reported by the test
            self.error = error

    def _claim(self, hazard_id: int) -> None:
        deadline = time.monotonic() + 60
        while True:
            try:
                self.robot.claim_hazard(hazard_id, timeout=3)
                self.won.add(hazard_id)
                return
            except ServiceRefused:
                self.lost.add(hazard_id)
                return
            except (ServiceTimeout, BrokerUnavailable):  # its request went to the worker just killed
                assert time.monotonic() < deadline, f"claim of hazard {hazard_id} never answered"


class HazardStream(threading.Thread):
    """An explorer detecting hazards in windows of 10 until stopped (and at least ``least`` of
    them), never more than ``AHEAD`` beyond what ``handed_out()`` says the wardens have: the stream
    goes on at the service's pace, whatever the store, and is still going when the test acts."""

    AHEAD = 40

    def __init__(self, robot: RobotClient, least: int, handed_out: Callable[[], int]) -> None:
        super().__init__(name=f"hazards-{robot.robot_id}", daemon=True)
        self.robot, self.least, self.handed_out = robot, least, handed_out
        self.sent = 0
        self.stopping = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            while not (self.stopping.is_set() and self.sent >= self.least):
                if self.sent - self.handed_out() > self.AHEAD:
                    self.stopping.wait(0.01)
                    continue
                self.robot.publish_many([("hazard", hazard(self.sent + n)) for n in range(10)])
                self.sent += 10
        except BaseException as error:  # reported by the test
            self.error = error

    def stop(self) -> int:
        self.stopping.set()
        self.join(120)
        assert not self.is_alive() and self.error is None, self.error
        return self.sent


def express_holder(bus: Bus, workers: list[subprocess.Popen[bytes]]) -> subprocess.Popen[bytes]:
    """The worker process holding shard 0, which consumes the express lane beside it."""

    def holder() -> subprocess.Popen[bytes] | None:
        now = time.time()
        for lease in bus.with_store(lambda store: store.leases.leases(shard_lease(0))):
            pid = int(lease.holder.split(":")[1])
            if lease.expires_at.timestamp() > now:
                return next((w for w in workers if w.pid == pid and w.poll() is None), None)
        return None

    return wait_for(holder, timeout=60, what="a live worker holding shard 0 and the express lane")


def test_the_express_lanes_single_active_consumer_is_all_the_hazard_service_needs(bus: Bus) -> None:
    """Two workers, a stream of hazards two wardens both claim, the active consumer killed with
    SIGKILL, a new worker started, and the next active consumer stopped with SIGTERM while hazards
    keep coming: every hazard id once, every claim won once, every hazard handed to each warden
    once, in order. Only the kill may announce again (at least once), never more than the batch
    in hand; the hand-over, where a worker finishes its batch before the next gets the lane, not.
    On SQLite: workers sharing a MongoDB store are tested by the ingest test above, and the hazard
    registry's conditional updates by the store's contract on both databases."""
    hazards = 300
    bus.settings = bus.settings.updated(ingest_shards=SHARDS)
    explorers = [bus.robot(bus.add(name, kind=RobotKind.EXPLORER)) for name in ("explorer1", "explorer2")]
    wardens = [
        ClaimingWarden(account, bus.robot(account))
        for account in (bus.add(name, kind=RobotKind.WARDEN) for name in ("warden1", "warden2"))
    ]

    def seen_by_both(count: int) -> bool:
        return all(len(warden.first_seen()) >= count for warden in wardens)

    with worker_processes(bus, 2) as workers:
        for warden in wardens:
            warden.robot.publish("localisation", {"localised": True})
            warden.start()
        # each explorer's share of what both wardens have been handed
        streams = [
            HazardStream(robot, hazards // 2, lambda: min(len(w.first_seen()) for w in wardens) // 2)
            for robot in explorers
        ]
        for stream in streams:
            stream.start()
        wait_for(lambda: seen_by_both(hazards // 4), timeout=120, what="a quarter of the hazards handed out")
        victim = express_holder(bus, workers)
        victim.kill()
        killed_at = time.monotonic()
        assert victim.wait(10) == -9
        survivor = express_holder(bus, workers)
        replacement = bus.spawn_worker("--no-recorder")
        workers.append(replacement)
        wait_for(
            lambda: sorted(bus.shard_holders().values()) == [2, 2], timeout=90, what="the new worker's share"
        )
        assert express_holder(bus, workers) is survivor, "shard 0 stays where it is"
        wait_for(lambda: seen_by_both(hazards // 2), timeout=120, what="half the hazards handed out")
        handed_over_at = time.monotonic()
        survivor.terminate()  # while the explorers go on
        assert survivor.wait(60) == 0, "SIGTERM stops a worker cleanly"
        assert express_holder(bus, workers) is replacement
        total = sum(stream.stop() for stream in streams)
        for warden in wardens:
            warden.expected = total
        for warden in wardens:
            warden.join(180)
            assert not warden.is_alive() and warden.error is None, warden.error

    assert total >= hazards
    registered = bus.with_store(lambda store: store.hazards.open_hazards("default"))
    assert sorted(h.hazard_id for h in registered) == list(range(1, total + 1)), "every hazard id once"
    assert len({(h.robot_id, h.epoch, h.seq) for h in registered}) == total
    assert all(h.state is HazardState.CLAIMED for h in registered)
    winners = {h.hazard_id: h.claimed_by for h in registered}
    for warden in wardens:
        assert warden.won | warden.lost == set(winners)
        assert warden.won == {i for i, by in winners.items() if by == warden.account.name}, "no double claim"
    for warden in wardens:
        assert warden.first_seen() == list(range(1, total + 1)), "each hazard handed out, in FIFO order"
        arrivals: dict[int, list[float]] = {hazard_id: [] for hazard_id in winners}
        for hazard_id, at in warden.copies:
            arrivals[hazard_id].append(at)
        again = {hazard_id: at[1:] for hazard_id, at in arrivals.items() if len(at) > 1}
        assert all(killed_at <= t < handed_over_at for times in again.values() for t in times), (
            f"{warden.account.name}: announced again only after the kill, never at the hand-over: {again}"
        )
        assert len(again) <= EXPRESS_PREFETCH, f"at most the killed worker's batch again: {sorted(again)}"
