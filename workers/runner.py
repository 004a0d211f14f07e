"""Start the workers against a broker and a store, and stop them cleanly on a signal."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta

import aio_pika
from aio_pika.abc import AbstractRobustConnection

from broker.accounts import SERVICE_USER, ensure_service_account
from broker.endpoint import BrokerEndpoint
from broker.management import ManagementAPI
from broker.topology import core_topology, declare
from fleetbus.config import Settings
from schemas.routing import (
    BEACON_DISCARD_QUEUE,
    DEAD_LETTER_EXCHANGE,
    INGEST_QUEUE,
    NOTIFY_EXCHANGE,
    RPC_QUEUE,
)
from workers.beacon_discards import DiscardCounter
from workers.beacons import KnownRobotsOnly, beacon_services
from workers.coordination import HazardCoordinator
from workers.ingest import IngestConsumer
from workers.maps import MapCheck, MapService, map_services
from workers.missions import MissionStamp
from workers.rpc import RpcServer
from workers.services import hazard_services
from workers.signals import stop_on_signals
from workers.store import Store, open_store
from workers.telemetry import BatteryWatch

log = logging.getLogger("fleetbus.worker")

PREFETCH = 512


@dataclass
class WorkerContext:
    connection: AbstractRobustConnection
    consumer: IngestConsumer
    rpc: RpcServer
    discards: DiscardCounter
    store: Store


def service_url(settings: Settings, endpoint: BrokerEndpoint) -> str:
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        return ensure_service_account(endpoint.amqp_url, api, settings.accounts_dir)


async def start_worker(settings: Settings, endpoint: BrokerEndpoint) -> WorkerContext:
    url = await asyncio.to_thread(service_url, settings, endpoint)
    store = open_store(settings)
    await store.open()
    connection = await aio_pika.connect_robust(url, client_properties={"connection_name": "fleetbus-worker"})
    channel = await connection.channel(publisher_confirms=True)
    await channel.set_qos(prefetch_count=PREFETCH)
    await declare(channel, [core_topology()])
    # fetched (not just named) so the robust channel re-consumes them after a broker restart
    queue = await channel.get_queue(INGEST_QUEUE)
    notify_exchange = await channel.get_exchange(NOTIFY_EXCHANGE)
    coordinator = HazardCoordinator(
        store, notify_exchange, SERVICE_USER, timedelta(seconds=settings.late_after_s)
    )
    consumer = IngestConsumer(
        channel,
        queue,
        store,
        await channel.get_exchange(DEAD_LETTER_EXCHANGE),
        max_message_bytes=settings.max_message_bytes,
        checks=[KnownRobotsOnly(store), MapCheck(store)],
        services=[
            MapService(store, notify_exchange, SERVICE_USER),
            coordinator,
            BatteryWatch(store, notify_exchange, SERVICE_USER, settings.battery_low_percent),
        ],
        enrichers=[MissionStamp(store)],
        batch_size=PREFETCH,
    )
    await coordinator.release_if_ready()  # hazards held before a restart, if the gate is open now
    rpc_channel = await connection.channel()
    await rpc_channel.set_qos(prefetch_count=32)
    rpc = RpcServer(
        rpc_channel,
        await rpc_channel.get_queue(RPC_QUEUE),
        {**hazard_services(store), **beacon_services(store), **map_services(store)},
    )
    await rpc.start()
    discard_channel = await connection.channel()
    await discard_channel.set_qos(prefetch_count=64)
    discards = DiscardCounter(discard_channel, await discard_channel.get_queue(BEACON_DISCARD_QUEUE), store)
    await discards.start()
    return WorkerContext(connection, consumer, rpc, discards, store)


async def run_worker(
    settings: Settings,
    endpoint: BrokerEndpoint,
    stop: asyncio.Event | None = None,
    on_started: Callable[[WorkerContext], None] | None = None,
) -> None:
    """Run until ``stop`` is set, or SIGTERM/SIGINT when run as the main program."""
    stop = stop or asyncio.Event()
    stop_on_signals(stop)
    context = await start_worker(settings, endpoint)
    log.info("worker consuming %s (store: %s)", INGEST_QUEUE, context.store.name)
    if on_started is not None:
        on_started(context)
    consuming = asyncio.create_task(context.consumer.run())
    stopping = asyncio.create_task(stop.wait())
    try:
        await asyncio.wait({consuming, stopping}, return_when=asyncio.FIRST_COMPLETED)
        await context.rpc.stop()
        await context.discards.stop()
        await context.consumer.stop()
        await consuming
    finally:
        stopping.cancel()
        await context.connection.close()
        await context.store.close()
        log.info("worker stopped: %s", context.consumer.stats)
