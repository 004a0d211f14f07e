"""Start the recorder against a broker and a store, and stop it cleanly on a signal."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fleetbus.limits import parse_retention, parse_ttl
from fleetbus.schemas.routing import RECORDER_QUEUE
from fleetbus.workers.recorder.capture import TypeNames
from fleetbus.workers.recorder.consumer import MissionLookup, RecorderConsumer, RecorderOptions
from fleetbus.workers.recorder.filters import RoutingFilter
from fleetbus.workers.recorder.retention import samples_retention
from fleetbus.workers.recorder.source import RecorderQueue
from fleetbus.workers.signals import stop_on_signals
from fleetbus.workers.store import Repositories, StoreSettings, open_recording_store, repositories_for
from fleetbus.workers.store.recordings import RecordingStore

if TYPE_CHECKING:
    from fleetbus.broker.endpoint import BrokerEndpoint
    from fleetbus.settings import Settings

log = logging.getLogger("fleetbus.recorder")


@dataclass
class RecorderContext:
    connection: RecorderQueue
    consumer: RecorderConsumer
    store: RecordingStore
    repositories: Repositories | None = None
    """The service's repositories, when the recorder asks them which mission each robot is recorded
    under (the channels) and why a dead letter was refused (the rejections)."""

    async def close(self) -> None:
        await self.connection.close()
        await self.store.close()
        if self.repositories is not None:
            await self.repositories.close()


def recorder_options(settings: Settings, **overrides: object) -> RecorderOptions:
    """The options the settings give (``FLEETBUS_RECORDER_*``), with command-line overrides."""
    options = RecorderOptions(
        filter=RoutingFilter(settings.recorder_include, settings.recorder_exclude),
        retention=parse_retention(settings.recorder_keep),
        max_message_bytes=settings.max_message_bytes,
        samples_keep=samples_retention(settings.recorder_samples_keep),
        ros_pieces_ttl=parse_ttl(settings.ros_pieces_ttl, "FLEETBUS_ROS_PIECES_TTL"),
    )
    return RecorderOptions(**{**options.__dict__, **overrides})  # type: ignore[arg-type]


async def declare_recording(url: str, cluster: bool = False) -> None:
    """The recorder's queue and its bindings (as the administrator, or the ``fleetbus`` account:
    they are the service's). `fleetbus worker` declares them before it consumes, so whatever is
    published from then on waits for its recorder child, even while that process is still
    starting (or restarting)."""
    # imported here, as in recorder_url: the recording process itself needs neither (its memory)
    from fleetbus.broker.topology import core_topology, declare_with_url, recorder_topology

    await declare_with_url(url, [core_topology(cluster=cluster), recorder_topology(cluster=cluster)])


def recorder_url(settings: Settings, endpoint: BrokerEndpoint) -> str:
    """As the administrator (:mod:`fleetbus.workers.setup`): the ``fleetbus-recorder`` account; its URL."""
    from fleetbus.broker.accounts import ensure_recorder_account
    from fleetbus.broker.management import ManagementAPI

    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        return ensure_recorder_account(endpoint.amqp_url, api, settings.accounts_dir)


async def start_recorder(
    settings: StoreSettings,
    url: str,
    options: RecorderOptions,
    missions: MissionLookup | None = None,
) -> RecorderContext:
    """Ready to consume, as the ``fleetbus-recorder`` account of ``url`` alone: its queue and
    bindings exist already (:mod:`fleetbus.workers.setup`, or the worker declared them). Without
    ``missions``, the service's store says which mission each robot is recorded under (its
    check-ins), as it does for the event log."""
    store = open_recording_store(settings)
    await store.open()
    names = TypeNames(await store.recorded_types(), options.max_types)
    repositories: Repositories | None = None
    if missions is None:
        repositories = repositories_for(settings)
        await repositories.open()
        missions = repositories.channels.recording_missions
    queue = RecorderQueue(url, RECORDER_QUEUE, options.batch_size, "fleetbus-recorder")
    await queue.open()
    return RecorderContext(
        queue,
        RecorderConsumer(
            queue,
            store,
            options,
            names,
            missions,
            repositories.rejections if repositories else None,
            repositories.housekeeping.count_bounded if repositories else None,
        ),
        store,
        repositories,
    )


async def run_recorder(
    settings: StoreSettings,
    url: str,
    options: RecorderOptions,
    stop: asyncio.Event | None = None,
    on_started: Callable[[RecorderContext], None] | None = None,
    missions: MissionLookup | None = None,
) -> None:
    """Record until ``stop`` is set, or SIGTERM/SIGINT when run as the main program; ``missions``
    stamps each robot's messages with the mission it is recorded under."""
    stop = stop or asyncio.Event()
    stop_on_signals(stop)
    context = await start_recorder(settings, url, options, missions)
    log.info("recorder consuming %s (store: %s)", RECORDER_QUEUE, context.store.name)
    if on_started is not None:
        on_started(context)
    consuming = asyncio.create_task(context.consumer.run())
    stopping = asyncio.create_task(stop.wait())
    kept = asyncio.create_task(context.connection.kept())
    try:
        await asyncio.wait({consuming, stopping, kept}, return_when=asyncio.FIRST_COMPLETED)
        if kept.done() and kept.exception() is not None:
            error = kept.exception()
            log.error("recorder gave up on the broker: %r; it stops (its parent starts it again)", error)
        await context.consumer.stop()
        await consuming
    finally:
        stopping.cancel()
        kept.cancel()
        await context.close()
        log.info("recorder stopped: %s", context.consumer.stats)
