"""The broker as the dashboard shows it: its nodes, the depth and consumers of each fleetbus
queue, who is connected, and the dead letters of the last hour.

One :class:`BrokerWatch` per API process asks the management API at most every
``console_broker_poll_s`` seconds, and only while a page asks for it: N open dashboards cost one
poll. The poll runs in the background; pages are given the last answer at once, so a management
API that hangs holds no page up. A management API that does not answer is shown as such, with why.

Dead letters are read as ``fleetbus dlq`` reads them (peeked from their queue, nothing removed,
each with the reason the store kept): at most ``console_dead_letters_peek`` of them, and only
when the queue's depth changed since the last read or a minute passed (letters age out of the
hour). The management API's depths lag the broker by its statistics interval (5 s by default).
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from typing import Any

from fastapi import Request

from fleetbus.api.console.broker_rates import AGE_S, EVERY_S, Rates, rates_of
from fleetbus.api.service import Service
from fleetbus.broker.dead_letter_queue import DeadLetter
from fleetbus.broker.management import ManagementAPI, oldest_by_user, users_of
from fleetbus.broker.served_certificate import ServedCertificate, served_certificate
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE

log = logging.getLogger("fleetbus.api.console")

#: The dead letters counted: those of the last hour.
WINDOW = timedelta(hours=1)
#: Read the dead letters again after this long even if their queue's depth did not change.
RECOUNT_S = 60.0
#: The queues the dashboard lists: the service's own.
QUEUE_PREFIX = "fleetbus."
#: What :meth:`Queue.of` reads of a queue.
QUEUE_COLUMNS = ("name", "type", "messages_ready", "messages_unacknowledged", "consumers", "state")
#: Read the broker's certificate again after this long (it changes when an operator replaces it).
CERTIFICATE_RECHECK_S = 600.0


@dataclass(frozen=True)
class Node:
    name: str
    running: bool
    mem_used: int
    mem_limit: int
    mem_alarm: bool
    disk_free: int
    disk_free_alarm: bool
    fd_used: int
    fd_total: int

    @classmethod
    def of(cls, node: dict[str, Any]) -> Node:
        return cls(
            node.get("name", "?"),
            bool(node.get("running")),
            int(node.get("mem_used") or 0),
            int(node.get("mem_limit") or 0),
            bool(node.get("mem_alarm")),
            int(node.get("disk_free") or 0),
            bool(node.get("disk_free_alarm")),
            int(node.get("fd_used") or 0),
            int(node.get("fd_total") or 0),
        )

    @property
    def healthy(self) -> bool:
        return self.running and not self.mem_alarm and not self.disk_free_alarm


@dataclass(frozen=True)
class Queue:
    name: str
    type: str
    ready: int
    unacked: int
    consumers: int
    state: str

    @classmethod
    def of(cls, queue: dict[str, Any]) -> Queue:
        return cls(
            queue["name"],
            queue.get("type", "classic"),
            int(queue.get("messages_ready") or 0),
            int(queue.get("messages_unacknowledged") or 0),
            int(queue.get("consumers") or 0),
            queue.get("state", "?"),
        )

    @property
    def depth(self) -> int:
        return self.ready + self.unacked

    @property
    def idle(self) -> bool:
        """No consumer, where one is expected (nothing consumes the dead letters: they wait for
        an operator)."""
        return not self.consumers and self.name != DEAD_LETTER_QUEUE


@dataclass(frozen=True)
class CertificateCheck:
    """The certificate the broker presents to clients, as last read; or why it could not be."""

    checked_at: datetime
    warn_days: float
    certificate: ServedCertificate | None = None
    problem: str | None = None

    @property
    def plain(self) -> bool:
        """The service reaches the broker without TLS: there was no certificate to read."""
        return self.certificate is None and self.problem is None

    @property
    def days_left(self) -> float | None:
        return self.certificate.days_left(self.checked_at) if self.certificate else None

    @property
    def state(self) -> str:
        """``ok``; ``expiring`` within ``warn_days``; ``expired``; ``unknown`` (not read, or plain)."""
        days = self.days_left
        if days is None:
            return "unknown"
        return "expired" if days <= 0 else "expiring" if days <= self.warn_days else "ok"


def check_certificate(urls: list[str], warn_days: float) -> CertificateCheck:
    """Read the certificate at the first of ``urls`` served over TLS (the service's broker URL,
    then its management API's)."""
    now = datetime.now(timezone.utc)
    for url in urls:
        try:
            found = served_certificate(url)
        except (OSError, ValueError) as error:  # ssl.SSLError is an OSError
            return CertificateCheck(now, warn_days, problem=f"could not be read: {error}")
        if found is not None:
            return CertificateCheck(now, warn_days, certificate=found)
    return CertificateCheck(now, warn_days)


@dataclass(frozen=True)
class BrokerHealth:
    """The management API's last answer, or why there is none."""

    polled_at: datetime | None = None
    nodes: list[Node] = field(default_factory=list)
    queues: list[Queue] = field(default_factory=list)
    connections: Counter[str] = field(default_factory=Counter)
    """Open connections on the service's virtual host, by user."""
    problem: str | None = "not asked yet"
    connected_since: dict[str, datetime] = field(default_factory=dict)
    """When each user's oldest open connection opened (a site's: its link up since)."""
    certificate: CertificateCheck | None = None
    rates: Rates | None = None
    """Messages a second published and delivered over the last hour (None: not asked, or the
    broker did not say)."""

    @property
    def known(self) -> bool:
        return self.problem is None

    def connected(self, user: str) -> int | None:
        """How many connections ``user`` has open; None when the broker could not be asked."""
        return self.connections.get(user, 0) if self.known else None

    def queue(self, name: str) -> Queue | None:
        return next((queue for queue in self.queues if queue.name == name), None)


@dataclass(frozen=True)
class DeadLetterCount:
    """The dead letters of the last hour, by reason."""

    counted_at: datetime | None = None
    by_reason: Counter[str] = field(default_factory=Counter)
    read: int = 0
    """Letters read from the queue (at most ``console_dead_letters_peek``, the oldest)."""
    in_queue: int = 0
    undated: int = 0
    """Letters read with no time of rejection (counted apart)."""
    dropped: int = 0
    """Older letters the full queue dropped since the store began (``fleetbus dlq`` says it too)."""
    problem: str | None = "not counted yet"

    @property
    def last_hour(self) -> int:
        return sum(self.by_reason.values())

    @property
    def partial(self) -> bool:
        """The queue holds more than was read: the newest letters were not seen."""
        return self.in_queue > self.read


def rejected_at(letter: DeadLetter) -> datetime | None:
    if not letter.rejected_at:
        return None
    try:
        moment = datetime.fromisoformat(letter.rejected_at)
    except ValueError:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=timezone.utc)


def count_recent(letters: list[DeadLetter], since: datetime) -> tuple[Counter[str], int]:
    """The letters rejected since ``since``, by reason; and how many carry no time."""
    times = [(letter, rejected_at(letter)) for letter in letters]
    recent = Counter(letter.reason for letter, moment in times if moment is not None and moment >= since)
    return recent, sum(1 for _, moment in times if moment is None)


def ask_broker(management: ManagementAPI, vhost: str) -> BrokerHealth:
    """The broker as the dashboard shows it, asked now: its nodes, the service's own queues, who
    is connected and since when, the message rates (blocking: four management API requests)."""
    nodes = management.list_nodes()
    queues = management.list_queues_named(vhost, QUEUE_PREFIX, QUEUE_COLUMNS)
    connections = management.list_vhost_connections(vhost)
    rates = rates_of(management.vhost_rate_samples(vhost, AGE_S, EVERY_S))
    return BrokerHealth(
        datetime.now(timezone.utc),
        [Node.of(node) for node in nodes],
        sorted((Queue.of(queue) for queue in queues), key=lambda queue: queue.name),
        users_of(connections),
        None,
        oldest_by_user(connections),
        rates=rates,
    )


class BrokerWatch:
    def __init__(self, service: Service) -> None:
        self._service = service
        self._poll_s = service.settings.console_broker_poll_s
        self._peek = service.settings.console_dead_letters_peek
        self.health = BrokerHealth()
        self.dead_letters = DeadLetterCount()
        self._task: asyncio.Task[None] | None = None
        self._started = -float("inf")
        self._counted: tuple[float, int | None] | None = None
        """When the dead letters were last read, and their queue's depth then."""
        self._certificate: tuple[float, CertificateCheck] | None = None

    def current(self) -> tuple[BrokerHealth, DeadLetterCount]:
        """The last answers; starts a new poll in the background when one is due."""
        now = asyncio.get_running_loop().time()
        if (self._task is None or self._task.done()) and now - self._started >= self._poll_s:
            self._started = now
            self._task = asyncio.create_task(self.poll(), name="console-broker-poll")
        return self.health, self.dead_letters

    async def poll(self) -> None:
        """Ask the management API; then read the dead letters, if their queue changed."""
        self.health = replace(await self._ask_broker(), certificate=await self._check_certificate())
        dlq = self.health.queue(DEAD_LETTER_QUEUE)
        depth = dlq.depth if dlq else None
        now = asyncio.get_running_loop().time()
        if self._counted is None or self._counted[1] != depth or now - self._counted[0] >= RECOUNT_S:
            self.dead_letters = await self._count_dead_letters(depth or 0)
            self._counted = (now, depth)

    async def _ask_broker(self) -> BrokerHealth:
        try:
            return await asyncio.to_thread(ask_broker, self._service.management, self._service.vhost)
        except Exception as error:  # any failure to ask is shown, never raised into the pages
            log.warning("console: the management API did not answer: %s", error)
            return BrokerHealth(problem=f"the management API did not answer: {error}")

    async def _check_certificate(self) -> CertificateCheck:
        now = asyncio.get_running_loop().time()
        if self._certificate is None or now - self._certificate[0] >= CERTIFICATE_RECHECK_S:
            urls = [self._service.admin_url, self._service.management.base_url]
            warn = self._service.settings.console_certificate_warn_days
            check = await asyncio.to_thread(check_certificate, urls, warn)
            if check.problem:
                log.warning("console: the broker's certificate %s", check.problem)
            self._certificate = (now, check)
        return self._certificate[1]

    async def _count_dead_letters(self, in_queue: int) -> DeadLetterCount:
        now = datetime.now(timezone.utc)
        try:
            letters = await self._service.dead_letters(self._peek)
            dropped = await self._service.dead_letter_queue.dropped()
        except Exception as error:  # any failure to read is shown, never raised into the pages
            log.warning("console: the dead letters could not be read: %s", error)
            return DeadLetterCount(now, problem=f"could not be read: {error}")
        recent, undated = count_recent(letters, now - WINDOW)
        return DeadLetterCount(now, recent, len(letters), max(in_queue, len(letters)), undated, dropped, None)


def broker_watch(request: Request) -> BrokerWatch:
    """The process's :class:`BrokerWatch` (made by the first page that asks)."""
    state = request.app.state
    if getattr(state, "broker_watch", None) is None:
        state.broker_watch = BrokerWatch(state.service)
    return state.broker_watch
