"""Start the workers against a broker and a store, and stop them cleanly on a signal."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Protocol

from aio_pika.abc import AbstractChannel, AbstractRobustConnection

from fleetbus.bounds import bounds
from fleetbus.broker.accounts import SERVICE_USER, ensure_service_account, vhost_of
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.shards import read_shard_map
from fleetbus.broker.sites import SITE_HAZARDS_QUEUE_ARGUMENTS
from fleetbus.broker.tls import aio_connect_robust
from fleetbus.broker.topology import INGEST_DELIVERY_LIMIT, core_topology, declare, replicated
from fleetbus.schemas.routing import (
    BEACON_DISCARD_QUEUE,
    EXPRESS_QUEUE,
    NOTIFY_EXCHANGE,
    OVERFLOW_QUEUE,
    RPC_QUEUE,
    SITE_HAZARDS_QUEUE,
    ingest_shard_queue,
)
from fleetbus.settings import Settings
from fleetbus.workers.attempts import AttemptLimit
from fleetbus.workers.beacon_discards import DiscardCounter
from fleetbus.workers.beacons import KnownRobotsOnly, beacon_services
from fleetbus.workers.coordination import GATED, HazardCoordinator, TeamChanges
from fleetbus.workers.express import ExpressLane
from fleetbus.workers.forwards import ForwardLog, SiteLocalOnly
from fleetbus.workers.hazard_uplink import HazardUplink
from fleetbus.workers.ingest import BROKER_ERRORS, BatchCheck, BatchService, IngestConsumer, IngestStats
from fleetbus.workers.maps import MapCheck, MapService, map_services
from fleetbus.workers.overflow import OverflowCounter
from fleetbus.workers.pruning import Pruner
from fleetbus.workers.rpc import RpcServer
from fleetbus.workers.services import hazard_services
from fleetbus.workers.shards import ShardPool
from fleetbus.workers.signals import stop_on_signals
from fleetbus.workers.site_hazards import SiteHazards
from fleetbus.workers.site_maps import SiteMapRelay
from fleetbus.workers.status import report_status
from fleetbus.workers.store import Repositories, repositories_for
from fleetbus.workers.tasks import stopped
from fleetbus.workers.telemetry import BatteryWatch

log = logging.getLogger("fleetbus.worker")

PREFETCH = 512
#: Hazards and localisations handled at once on the express lane: few, each batch written on the
#: caller's thread (:data:`~fleetbus.workers.store.event_log.SMALL_BATCH`).
EXPRESS_BATCH = 16
#: Hazards and localisations delivered and not yet acked on the express lane. Many more than a
#: batch: a batch is acked only once its operators' copies are confirmed, which took up to a
#: second while the recorder's queue took a backlog; with 16 the broker could stop delivering
#: hazards until those confirms came (decision 0014).
EXPRESS_PREFETCH = 256


@dataclass
class WorkerContext:
    connection: AbstractRobustConnection
    shards: ShardPool
    rpc: RpcServer
    discards: DiscardCounter
    repositories: Repositories
    pruner: Pruner
    overflow: OverflowCounter
    site_hazards: SiteHazards
    """At central: applies the sites' hazard states."""
    hazard_uplink: HazardUplink
    """At a site: sends central its hazards' states."""
    stats: IngestStats = field(default_factory=IngestStats)
    """Counters of every shard this worker consumed."""


@dataclass
class QueueConsumer:
    """One ingest queue consumed on a channel of its own, so it can be let go without touching the others."""

    queue: str
    channel: AbstractChannel
    consumer: IngestConsumer
    task: asyncio.Task[None]

    async def stop(self) -> None:
        await self.consumer.stop()
        await stopped(self.task, f"consuming {self.queue}")
        # what was received but not acked (the store down at SIGTERM) goes back to the queue
        with contextlib.suppress(*BROKER_ERRORS):
            await self.channel.close()


class Lane(Protocol):
    """A queue being consumed: a shard's on the worker's connection, or the express lane on a
    thread of its own (:class:`~fleetbus.workers.express.ExpressLane`)."""

    @property
    def task(self) -> asyncio.Future[None]:
        """Completes when consuming ended by itself (with its error, if it failed)."""
        ...

    async def stop(self) -> None: ...


@dataclass
class ShardConsumer:
    """A shard's queue; the holder of shard 0 also takes the express lane, so the two move together.
    The express lane's single active consumer is the only one to run the hazard service."""

    shard: int
    queues: list[Lane]
    done: asyncio.Future[None] = field(init=False)
    """Completes when one of its queues stopped being consumed by itself."""

    def __post_init__(self) -> None:
        self.done = asyncio.ensure_future(_first_to_end([queue.task for queue in self.queues]))

    async def stop(self) -> None:
        await asyncio.gather(*(queue.stop() for queue in self.queues))


async def _first_to_end(tasks: list[asyncio.Future[None]]) -> None:
    done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    for task in done:
        task.result()  # its error, if it failed


async def ingest_consumer(
    settings: Settings,
    channel: AbstractChannel,
    queue_name: str,
    repositories: Repositories,
    stats: IngestStats,
    *,
    express: bool,
) -> IngestConsumer:
    """The consumer of an ingest shard, or (``express``) of the express lane, on ``channel``."""
    prefetch = EXPRESS_PREFETCH if express else PREFETCH
    await channel.set_qos(prefetch_count=prefetch)
    # fetched (not just named) so the robust channel re-consumes it after a broker restart
    queue = await channel.get_queue(queue_name)
    notify_exchange = await channel.get_exchange(NOTIFY_EXCHANGE)
    forward_log = ForwardLog(repositories.sites, timedelta(seconds=settings.late_after_s))
    checks: list[BatchCheck] = []
    control: TeamChanges | None = None
    finishing = None
    if express:
        # the hazard service runs on the express lane only: its single active consumer is the
        # one party that registers hazards and announces them, so it needs no lock across workers
        late_after = timedelta(seconds=settings.late_after_s)
        coordinator = HazardCoordinator(
            repositories.hazards, notify_exchange, channel.default_exchange, SERVICE_USER, late_after
        )
        services: list[BatchService] = [SiteLocalOnly(coordinator, repositories.sites), forward_log]
        control = TeamChanges(coordinator)
        finishing = coordinator.take_finishing
    else:
        checks = [KnownRobotsOnly(repositories.hazards), MapCheck(repositories.maps)]
        services = [
            MapService(
                repositories.maps,
                notify_exchange,
                SERVICE_USER,
                SiteMapRelay(repositories.sites, repositories.maps, channel).relay,
            ),
            BatteryWatch(repositories.events, notify_exchange, SERVICE_USER, settings.battery_low_percent),
            forward_log,
        ]
    return IngestConsumer(
        channel,
        queue,
        repositories.events,
        repositories.rejections,
        max_message_bytes=settings.max_message_bytes,
        checks=checks,
        services=services,
        urgent=GATED,  # the wardens wait for hazards; the gate opens on localisation
        batch_size=EXPRESS_BATCH if express else prefetch,
        stats=stats,
        # the express queue is classic: the worker keeps its delivery limit
        attempts=AttemptLimit(repositories.attempts, INGEST_DELIVERY_LIMIT) if express else None,
        # on stop, the next worker gets the express lane only once this batch is done
        exclusive=express,
        control=control,
        finishing=finishing,
    )


#: Seconds between the worker's reconnection attempts (aio-pika's default is 5); on a cluster each
#: attempt goes to the next node's address (:mod:`fleetbus.broker.failover`).
RECONNECT_INTERVAL_S = 1.0


def service_url(settings: Settings, endpoint: BrokerEndpoint) -> str:
    """As the administrator (:mod:`fleetbus.workers.setup`): the ``fleetbus`` account; returns its URL."""
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        url = ensure_service_account(endpoint.amqp_url, api, settings.accounts_dir)
        vhost = vhost_of(endpoint.amqp_url)
        stray = read_shard_map(api, vhost, settings.ingest_shards).stray()
    if stray:
        log.warning(
            "robots bound to a shard beyond FLEETBUS_INGEST_SHARDS=%d, or to several: %s; "
            "run `fleetbus shards rebalance`",
            settings.ingest_shards,
            ", ".join(stray),
        )
    return url


async def start_worker(settings: Settings, url: str) -> WorkerContext:
    """Consuming, as the ``fleetbus`` account of ``url`` alone (made by :mod:`fleetbus.workers.setup`)."""
    repositories = repositories_for(settings)
    await repositories.open()

    async def connect(name: str) -> AbstractRobustConnection:
        return await aio_connect_robust(
            url, client_properties={"connection_name": name}, reconnect_interval=RECONNECT_INTERVAL_S
        )

    connection = await connect("fleetbus-worker")
    setup = await connection.channel()
    await declare(setup, [core_topology(settings.ingest_shards, cluster=settings.cluster)])
    await setup.close()
    stats = IngestStats()

    async def consume(queue_name: str) -> QueueConsumer:
        channel = await connection.channel(publisher_confirms=True)
        consumer = await ingest_consumer(settings, channel, queue_name, repositories, stats, express=False)
        task = asyncio.create_task(consumer.run(), name=f"fleetbus-{queue_name}")
        log.info("consuming %s", queue_name)
        return QueueConsumer(queue_name, channel, consumer, task)

    async def consume_express(own: AbstractRobustConnection, store: Repositories) -> IngestConsumer:
        """The express lane's consumer, on its own connection and store (:mod:`.express`)."""
        channel = await own.channel(publisher_confirms=True)
        consumer = await ingest_consumer(settings, channel, EXPRESS_QUEUE, store, stats, express=True)
        log.info("consuming %s", EXPRESS_QUEUE)
        return consumer

    async def consume_shard(shard: int) -> ShardConsumer:
        lanes: list[Lane] = [await consume(ingest_shard_queue(shard))]
        if shard == 0:
            express = ExpressLane(repositories, connect, consume_express)
            try:
                await express.start()
            except BaseException:  # the shard's lane, started first, must not go on consuming alone
                await ShardConsumer(shard, lanes).stop()
                raise
            lanes.append(express)
        return ShardConsumer(shard, lanes)

    shards = ShardPool(repositories.leases, settings.ingest_shards, consume_shard)
    await shards.start()
    rpc_channel = await connection.channel()
    await rpc_channel.set_qos(prefetch_count=32)
    rpc = RpcServer(
        rpc_channel,
        await rpc_channel.get_queue(RPC_QUEUE),
        {
            **hazard_services(repositories.hazards, repositories.channels),
            **beacon_services(repositories.beacons, repositories.events, settings.beacon_window_max),
            **map_services(repositories.maps),
        },
    )
    await rpc.start()
    discard_channel = await connection.channel()
    await discard_channel.set_qos(prefetch_count=64)
    discards = DiscardCounter(
        discard_channel, await discard_channel.get_queue(BEACON_DISCARD_QUEUE), repositories.discards
    )
    await discards.start()
    overflow = OverflowCounter(
        discard_channel, await discard_channel.get_queue(OVERFLOW_QUEUE), repositories.housekeeping
    )
    await overflow.start()
    sites_channel = await connection.channel(publisher_confirms=True)
    await sites_channel.set_qos(prefetch_count=32)
    site_hazards = SiteHazards(
        sites_channel,
        await sites_channel.declare_queue(
            SITE_HAZARDS_QUEUE,
            durable=True,
            arguments=replicated(SITE_HAZARDS_QUEUE_ARGUMENTS, settings.cluster),
        ),
        repositories.hazards,
        repositories.sites,
        repositories.rejections,
    )
    await site_hazards.start()
    hazard_uplink = HazardUplink(sites_channel, repositories.hazards)
    hazard_uplink.start()
    pruner = Pruner(
        repositories.housekeeping,
        repositories.leases,
        repositories.maps,
        repositories.alerts,
        bounds(settings),
        shards.holder,
        not_a_site=lambda: hazard_uplink.not_a_site,
    )
    pruner.start()
    return WorkerContext(
        connection, shards, rpc, discards, repositories, pruner, overflow, site_hazards, hazard_uplink, stats
    )


async def run_worker(
    settings: Settings,
    url: str,
    stop: asyncio.Event | None = None,
    on_started: Callable[[WorkerContext], None] | None = None,
) -> None:
    """Run until ``stop`` is set, or SIGTERM/SIGINT when run as the main program."""
    stop = stop or asyncio.Event()
    stop_on_signals(stop)
    context = await start_worker(settings, url)
    log.info(
        "worker %s shares %d ingest shards, consuming %s (store: %s)",
        context.shards.holder,
        context.shards.shards,
        sorted(context.shards.held) or "none yet",
        context.repositories.name,
    )
    if on_started is not None:
        on_started(context)
    failing = asyncio.create_task(context.shards.wait_failed())
    stopping = asyncio.create_task(stop.wait())
    reported = asyncio.Event()
    reporting = asyncio.create_task(
        report_status(
            context.repositories.statuses,
            context.shards.holder,
            context.stats,
            reported,
            lambda: {
                "rpc_internal_errors": context.rpc.internal_errors,
                "rpc_bad_requests": context.rpc.bad_requests,
                "hazard_states_sent": context.hazard_uplink.sent,
                **{f"site_hazards.{what}": n for what, n in context.site_hazards.counts.items()},
            },
        )
    )
    try:
        await asyncio.wait({failing, stopping}, return_when=asyncio.FIRST_COMPLETED)
        await context.rpc.stop()
        await context.discards.stop()
        await context.pruner.stop()
        await context.overflow.stop()
        await context.site_hazards.stop()
        await context.hazard_uplink.stop()
        await context.shards.stop()
        reported.set()  # a last status, with the counts of the last batches
        await reporting
        if failing.done() and (error := failing.result()) is not None:
            raise error
    finally:
        failing.cancel()
        stopping.cancel()
        reporting.cancel()
        await context.connection.close()
        await context.repositories.close()
        log.info("worker stopped: %s", context.stats)
