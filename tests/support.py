"""Test helpers that run fleetbus against the real broker: a fresh virtual host per test."""

from __future__ import annotations

import asyncio
import itertools
import os
import subprocess
import sys
import threading
import time
import uuid
from collections import Counter
from collections.abc import Awaitable, Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlsplit

import pika

from fleetbus.api.services.accounts import Accounts, open_accounts
from fleetbus.broker.accounts import Account, Role, fresh_vhost
from fleetbus.broker.dead_letter_queue import DeadLetter, peek_dead_letters
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.retry import retrying
from fleetbus.broker.uplink import CLASSES
from fleetbus.broker.urls import without_password
from fleetbus.publishers.client import RobotClient, outbox_folder
from fleetbus.publishers.outbox import Outbox
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import Event
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EXPRESS_TYPES, RobotKind, inbox_queue
from fleetbus.settings import Settings, load_settings
from fleetbus.workers.recorder.consumer import MissionLookup
from fleetbus.workers.recorder.runner import recorder_options
from fleetbus.workers.setup import ServiceAccounts, set_up_service
from fleetbus.workers.store import Repositories, open_recording_store, run_with_repositories
from fleetbus.workers.store.base import EventQuery, EventRecord, StoreUnavailable
from fleetbus.workers.store.ledger import Gap
from fleetbus.workers.store.recordings import RecordedMessage, RecordQuery
from fleetbus_dev.recorder_thread import RecorderThread
from fleetbus_dev.worker_thread import WorkerThread
from tests.factories import hazard, status
from tests.link import NetworkLink

T = TypeVar("T")
EXPRESS_TYPE_NAMES = frozenset(event_type.value for event_type in EXPRESS_TYPES)
PROJECT_ROOT = Path(__file__).resolve().parent.parent
#: The registry's role of a test's account of each broker role.
USER_ROLES = {Role.ROBOT: UserRole.ROBOT, Role.OPERATOR: UserRole.OPERATOR, Role.USER: UserRole.GUEST}


def wait_for(
    condition: Callable[[], T], timeout: float = 30.0, what: str = "condition", interval: float = 0.05
) -> T:
    """Poll ``condition`` until it returns something truthy; fail with ``what`` at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(
                f"timed out after {timeout:.0f} s waiting for {what} (last value: {value!r})"
            )
        time.sleep(interval)


def read_inbox(
    amqp_url: str, robot: str, until: Callable[[list[Notification]], bool], timeout: float
) -> list[Notification]:
    """What the broker delivers to ``robot``'s inbox, repeats included, read with ``amqp_url``'s
    login until ``until(received)`` holds or nothing comes for ``timeout`` s (the robot client
    would skip a notification it handed out already, and rebuild on start: this reads the inbox
    itself)."""
    connection = blocking_connection(amqp_url)
    received: list[Notification] = []
    try:
        channel = connection.channel()
        for method, _, body in channel.consume(inbox_queue(robot), inactivity_timeout=timeout):
            if method is None:
                break
            received.append(Notification.model_validate_json(body))
            channel.basic_ack(method.delivery_tag)
            if until(received):
                break
    finally:
        connection.close()
    return received


def notifications_until(
    robot: RobotClient, sentinel: Callable[[Notification], bool], timeout: float = 30.0
) -> list[Notification]:
    """What ``robot`` receives up to and including the first notification ``sentinel`` picks.

    The sentinel is sent after whatever must not arrive, along the same path (an event of the
    same lane, announced by the workers): the inbox is FIFO, so the notifications before it are
    every one sent before it, and "nothing else arrived" is proven without a fixed wait."""
    received: list[Notification] = []
    deadline = time.monotonic() + timeout
    while not received or not sentinel(received[-1]):
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no sentinel within {timeout:.0f} s; received {received!r}")
        received.extend(robot.receive(1, timeout=left))
    return received


@dataclass
class Bus:
    """One test's slice of the real broker: its own virtual host, data directory and accounts."""

    endpoint: BrokerEndpoint
    api: ManagementAPI
    vhost: str
    settings: Settings

    @property
    def admin_url(self) -> str:
        assert self.settings.amqp_url is not None
        return self.settings.amqp_url

    accounts: list[str] = field(default_factory=list)
    clients: list[RobotClient] = field(default_factory=list)
    _service: ServiceAccounts | None = None

    def service_accounts(self) -> ServiceAccounts:
        """``fleetbus setup`` on the test's virtual host (once): the accounts the worker and the
        recorder run with, their passwords kept in the test's data directory."""
        if self._service is None:
            admin = replace(self.endpoint, amqp_url=self.admin_url)
            self._service = asyncio.run(set_up_service(self.settings, admin))
        return self._service

    def add(self, name: str, role: Role = Role.ROBOT, kind: RobotKind | None = None) -> Account:
        """A new user or robot, recorded in the test's account registry with its broker account
        (through the accounts service, as `fleetbus users add` makes one); users are broker-wide,
        so one left by an aborted run is re-keyed."""
        self.accounts.append(name)
        made = self.with_accounts(
            lambda accounts: accounts.provision(name, USER_ROLES[role], kind, "tests", rotate=True)
        )
        return Account(name, role, made.internal_url)

    def with_accounts(self, work: Callable[[Accounts], Awaitable[T]]) -> T:
        """Run ``work`` with the accounts service on the test's registry and virtual host."""

        async def go() -> T:
            async with open_accounts(self.settings, self.admin_url, self.endpoint.management_url) as opened:
                return await work(opened.accounts)

        return asyncio.run(go())

    def remove_accounts(self) -> None:
        for name in self.accounts:
            self.api.delete_user(name)

    def robot(self, account: Account, via: NetworkLink | None = None, **kwargs: Any) -> RobotClient:
        """A connected robot client (through ``via`` if given), its personal database in the test folder."""
        url = via.url(account.amqp_url) if via else account.amqp_url
        kwargs.setdefault("late_after_s", self.settings.late_after_s)  # as the test's service flags them
        client = RobotClient(url, state_dir=self.settings.robots_dir, **kwargs)
        self.clients.append(client)
        client.connect()
        return client

    def close_robots(self) -> None:
        for client in self.clients:
            client.close(flush_timeout=0)  # what a test left waiting stays; the test is over

    def spawn_robot(self, url: str, *args: str) -> subprocess.Popen[str]:
        """A robot as its own process (``tests.robot_process``), to be killed for real; its URL (with
        its password) on its standard input, never in its arguments."""
        process = subprocess.Popen(
            [sys.executable, "-m", "tests.robot_process", str(self.settings.robots_dir), *args],
            cwd=PROJECT_ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=open(self.settings.data_dir / f"robot-{uuid.uuid4().hex[:6]}.log", "wb"),
            text=True,
        )
        assert process.stdin is not None
        process.stdin.write(url + "\n")
        process.stdin.close()
        return process

    def outbox(self, robot: str) -> Outbox:
        """A robot's outbox as `fleetbus outbox` reads it (read-only; the robot may be running)."""
        return Outbox(outbox_folder(self.settings.robots_dir, robot), read_only=True)

    def gaps(self, robot: str | None = None) -> list[Gap]:
        return self.with_store(lambda store: store.events.gaps(robot))

    @contextmanager
    def worker(self) -> Iterator[WorkerThread]:
        thread = WorkerThread(self.settings, self.service_accounts().service_url).start()
        try:
            yield thread
        finally:
            thread.stop()

    @contextmanager
    def recorder(self, missions: MissionLookup | None = None, **options: Any) -> Iterator[RecorderThread]:
        """The recorder, with these :class:`RecorderOptions` over the settings' ones."""
        options_ = recorder_options(self.settings, **options)
        thread = RecorderThread(
            self.settings, self.service_accounts().recorder_url, options_, missions
        ).start()
        try:
            yield thread
        finally:
            thread.stop()

    def recorded(self, type: str, **query: Any) -> list[RecordedMessage]:
        """Records of ``type`` in the test's recording (a :class:`RecordQuery`'s fields)."""

        async def go() -> list[RecordedMessage]:
            async with open_recording_store(self.settings) as store:
                return await store.find_recorded(RecordQuery(type, **query))

        return asyncio.run(go())

    def publish_raw(self, account: Account, routing_key: str, body: bytes, **properties: Any) -> None:
        """Publish as the account with pika, confirmed: what any AMQP client of a robot could send."""
        connection = blocking_connection(account.amqp_url)
        try:
            channel = connection.channel()
            channel.confirm_delivery()
            properties.setdefault("content_type", "application/json")
            props = pika.BasicProperties(user_id=account.name, delivery_mode=2, **properties)
            channel.basic_publish(f"{account.name}.events", routing_key, body, props, mandatory=True)
        finally:
            connection.close()

    def worker_env(self) -> dict[str, str]:
        """The environment of a `fleetbus` command on the test's slice, as the administrator."""
        env = self._env()
        env.update(FLEETBUS_AMQP_URL=self.admin_url, FLEETBUS_MANAGEMENT_URL=self.endpoint.management_url)
        return env

    def service_env(self) -> dict[str, str]:
        """The environment of `fleetbus worker` or `recorder run`: the service account's URL without
        its password (kept in the data directory by :meth:`service_accounts`), no administrator."""
        env = self._env()
        env["FLEETBUS_SERVICE_URL"] = without_password(self.service_accounts().service_url)
        return env

    def _env(self) -> dict[str, str]:
        broker = (
            "FLEETBUS_AMQP_URL",
            "FLEETBUS_MANAGEMENT_URL",
            "FLEETBUS_SERVICE_URL",
            "FLEETBUS_MONGODB_URL",
        )
        env = {key: value for key, value in os.environ.items() if key not in broker}
        env.update(
            FLEETBUS_DATA_DIR=str(self.settings.data_dir),
            FLEETBUS_INGEST_SHARDS=str(self.settings.ingest_shards),
            FLEETBUS_CLUSTER="true" if self.settings.cluster else "false",
        )
        if self.settings.mongodb_url is not None:  # the test's own database, not the server's default one
            env["FLEETBUS_MONGODB_URL"] = self.settings.mongodb_url
        if self.endpoint.management_url.startswith("https:"):  # the run's CA, not one in the test's folder
            env.setdefault("FLEETBUS_TLS_CA", str(load_settings().ca_file))
        return env

    def spawn_worker(
        self, *options: str, module: str = "fleetbus", env: dict[str, str] | None = None
    ) -> subprocess.Popen[bytes]:
        """The worker as its own process (``python -m fleetbus worker``), to be killed for real;
        ``module`` runs another entry point (``tests.faulty_worker``) with the same options;
        ``env``: settings over :meth:`service_env`'s."""
        log = open(self.settings.data_dir / f"worker-{uuid.uuid4().hex[:6]}.log", "wb")
        command = [sys.executable, "-m", module, *(["worker"] if module == "fleetbus" else []), *options]
        return subprocess.Popen(
            command,
            env={**self.service_env(), **(env or {})},
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    def with_store(self, operation: Callable[[Repositories], Awaitable[T]], patience: float = 60.0) -> T:
        """Run one operation on a fresh connection to the test's store (what an operator would see).

        A store that does not answer a new connection in time (mongoeco's single-threaded server
        behind a busy worker on a loaded machine) is tried again until ``patience`` runs out: the
        workers retry it too (:class:`StoreUnavailable` is transient)."""
        attempt = retrying("the test's store", on=StoreUnavailable, deadline=patience)
        return attempt(run_with_repositories, self.settings, operation)

    def find(self, query: EventQuery | None = None) -> list[EventRecord]:
        return self.with_store(lambda store: store.events.find_events(query or EventQuery()))

    def count(self, type: str | None = None, robot_id: str | None = None) -> int:
        return self.with_store(lambda store: store.events.count_events(type, robot_id))

    def shard_holders(self) -> Counter[str]:
        """How many ingest shards each worker holds an unexpired lease on, by worker."""
        leases = self.with_store(lambda store: store.leases.leases("shard:"))
        now = time.time()
        return Counter(lease.holder for lease in leases if lease.expires_at.timestamp() > now)

    def dead_letters(self) -> list[DeadLetter]:
        """The dead-letter queue as `fleetbus dlq` lists it: each letter with the reason the store kept."""
        return peek_dead_letters(
            self.admin_url, reasons=lambda keys: self.with_store(lambda s: s.rejections.rejections(keys))
        )

    @contextmanager
    def admin_channel(self) -> Iterator[Any]:
        """A pika channel as the administrator of the test's virtual host."""
        connection = blocking_connection(self.admin_url)
        try:
            yield connection.channel()
        finally:
            if connection.is_open:
                connection.close()

    def ready_messages(self, queue: str) -> int:
        """Messages ready in ``queue`` now (AMQP passive declare; the HTTP API lags seconds)."""
        connection = blocking_connection(self.admin_url)
        try:
            return connection.channel().queue_declare(queue, passive=True).method.message_count
        finally:
            connection.close()


def network_link(links: list[NetworkLink], account: Account) -> NetworkLink:
    """A link from robots to the broker of ``account`` that the test can break (kept in ``links``,
    the ``link_for`` fixture, to be stopped after the test)."""
    link = NetworkLink(urlsplit(account.amqp_url).port or 5672).start()
    links.append(link)
    return link


@contextmanager
def fresh_bus(
    endpoint: BrokerEndpoint, api: ManagementAPI, data_dir: Path, prefix: str = "test"
) -> Iterator[Bus]:
    """A new virtual host and data directory on ``endpoint``; accounts and vhost removed after."""
    vhost = f"{prefix}-{uuid.uuid4().hex[:10]}"
    admin_url = fresh_vhost(api, endpoint.amqp_url, vhost)
    settings = load_settings().updated(
        data_dir=data_dir,
        amqp_url=admin_url,
        management_url=endpoint.management_url,
        mongodb_url=None,
    )
    bus = Bus(endpoint, api, vhost, settings)
    try:
        yield bus
    finally:
        bus.close_robots()
        bus.remove_accounts()
        api.delete_vhost(vhost)


def read_line(process: subprocess.Popen[str], expected: str, timeout: float = 60.0) -> str:
    """Wait until ``process`` prints a line starting with ``expected`` (returned); fail if it ends or
    time runs out."""
    return printed_until(process, expected, timeout)[-1]


def printed_until(process: subprocess.Popen[str], expected: str, timeout: float = 60.0) -> list[str]:
    """The lines ``process`` prints up to and with one starting with ``expected``; fail if it ends
    or time runs out. Nothing past that line is read, so the caller may read on.

    The lines are read by a thread, not after a ``select``: the pipe's reader buffers what the
    process wrote at once, so a line may wait in that buffer while the pipe itself has nothing."""
    assert process.stdout is not None
    stdout = process.stdout
    lines: list[str] = []
    found = threading.Event()

    def read() -> None:
        while line := stdout.readline():
            lines.append(line)
            if line.startswith(expected):
                found.set()
                return
        found.set()  # the process ended

    threading.Thread(target=read, name=f"reading {process.pid}", daemon=True).start()
    if not found.wait(timeout):
        printed = "".join(lines)
        raise AssertionError(f"the process did not print {expected!r} within {timeout:.0f} s: {printed}")
    if not lines or not lines[-1].startswith(expected):
        printed = "".join(lines)
        raise AssertionError(f"the process ended ({process.wait()}) before printing {expected!r}: {printed}")
    return lines


#: An event as the store keys it within its robot: (epoch, seq). Sorted, the epochs of one robot
#: come in the order its client starts began, each one's events in the order numbered.
EventKey = tuple[str, int]


def keys(events: Iterable[Event]) -> list[EventKey]:
    return [(event.epoch, event.seq) for event in events]


def worker_lane(event_type: str) -> str:
    """Hazards and localisations take the express lane: they may overtake the robot's other events."""
    return "express" if event_type in EXPRESS_TYPE_NAMES else "shard"


def site_lane(event_type: str) -> str:
    """At central, for a site's robot: also the uplink's class it came by (:mod:`fleetbus.broker.uplink`)."""
    uplink = next(u.name for u in CLASSES if event_type in {t.value for t in u.types})
    return f"{uplink} uplink, {worker_lane(event_type)}"


def assert_stored_once_in_order(
    bus: Bus, robot: str, sent: Sequence[EventKey], lane_of: Callable[[str], str] = worker_lane
) -> None:
    """The store holds each of ``sent`` (epoch, seq) exactly once, and received each epoch's
    events in sequence order within each lane (``lane_of`` an event type). Order holds per
    (robot, epoch): two clients with the robot's account at once number apart. An event the broker
    redelivered (its first consumer lost before acking it) may come after later ones: RabbitMQ
    keeps a queue's order only for messages not redelivered."""
    records = sorted(bus.find(EventQuery(robot_id=robot)), key=lambda record: (record.epoch, record.seq))
    assert [(r.epoch, r.seq) for r in records] == sorted(sent), f"{robot}: every event once, nothing else"
    for epoch in {r.epoch for r in records}:
        for lane in {lane_of(r.type) for r in records}:
            in_lane = [r for r in records if r.epoch == epoch and lane_of(r.type) == lane]
            overtaken = [
                f"seq {a.seq} ({a.type}) at {a.received_at:%H:%M:%S.%f}, "
                f"seq {b.seq} ({b.type}) at {b.received_at:%H:%M:%S.%f}"
                for a, b in itertools.pairwise(in_lane)
                if b.received_at < a.received_at and not a.redelivered
            ]
            assert not overtaken, (
                f"{robot}: a later {lane} event of epoch {epoch} was taken before an earlier one: "
                f"{overtaken[:5]}"
            )


class Publishing:
    """A robot publishing on a thread of its own, as robot code does, until :meth:`stop`.

    Every ``period`` seconds it publishes a status event, and a hazard every ``hazard_every``-th
    time, with ``publish`` as robot code calls it: confirmed while the broker answers, queued in
    the outbox at once while it does not. ``sent`` holds every (epoch, seq) it was given.
    """

    def __init__(self, robot: RobotClient, period: float = 0.02, hazard_every: int = 10) -> None:
        self.robot = robot
        self.sent: list[EventKey] = []
        self.error: BaseException | None = None
        self._period = period
        self._hazard_every = hazard_every
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"publishing-{robot.robot_id}", daemon=True)

    def start(self) -> Publishing:
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                n = len(self.sent)
                item = ("hazard", hazard(n)) if n % self._hazard_every == 0 else ("status", status(80))
                event = self.robot.publish(*item)
                self.sent.append((event.epoch, event.seq))
                self._stop.wait(self._period)  # the robot's publishing rate
        except BaseException as error:  # reported by stop()
            self.error = error

    def stop(self) -> list[EventKey]:
        self._stop.set()
        self._thread.join(30)
        if self.error is not None:
            raise self.error
        return self.sent
