"""The raw broker, with the client libraries fleetbus uses: what every other figure is compared with.

publish   pika, persistent messages, pipelined confirms (windows of 1,000)
consume   aio-pika, manual ack per message, a prefetch
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping
from typing import Any

import aio_pika
import pika

from bench.scenario import Context, Figures
from fleetbus.broker.tls import aio_connect
from fleetbus.broker.topology import INGEST_QUEUE_ARGUMENTS, QueueSpec, Topology, declare_with_url
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.tls import blocking_connection

RAW_QUEUE = "bench.raw"
SIZE = 512
WINDOW = 1000
PREFETCH = 512


def ingest_queue_arguments() -> dict[str, Any]:
    """The arguments of fleetbus's ingest shard queues (quorum, single active consumer, ...)."""
    return dict(INGEST_QUEUE_ARGUMENTS)


def declare_queue(admin_url: str, arguments: Mapping[str, Any], name: str = RAW_QUEUE) -> None:
    asyncio.run(declare_with_url(admin_url, [Topology(queues=(QueueSpec(name, dict(arguments)),))]))


def publish_bodies(
    url: str, exchange: str, routing_key: str, bodies: list[bytes], **properties: Any
) -> float:
    """Publish ``bodies`` persistent, confirms pipelined a window at a time; messages a second."""
    connection = blocking_connection(url)
    try:
        confirms = PipelinedConfirms(connection, connection.channel(), timeout=120)
        props = pika.BasicProperties(delivery_mode=2, **properties)
        started = time.perf_counter()
        for start in range(0, len(bodies), WINDOW):
            window = bodies[start : start + WINDOW]
            confirms.publish([Outgoing(exchange, routing_key, body, props) for body in window], 120)
        return len(bodies) / (time.perf_counter() - started)
    finally:
        if connection.is_open:
            connection.close()


def raw_publish(url: str, count: int, size: int, queue: str = RAW_QUEUE) -> float:
    """``count`` persistent messages of ``size`` bytes into ``queue``; messages a second."""
    return publish_bodies(url, "", queue, [b"x" * size] * count)


async def raw_consume(url: str, count: int, queue: str = RAW_QUEUE, prefetch: int = PREFETCH) -> float:
    """Consume ``count`` messages from ``queue``, acking each; messages a second."""
    connection = await aio_connect(url)
    async with connection:
        channel = await connection.channel()
        await channel.set_qos(prefetch_count=prefetch)
        source = await channel.get_queue(queue, ensure=False)
        done = asyncio.Event()
        seen = 0

        async def on_message(message: aio_pika.abc.AbstractIncomingMessage) -> None:
            nonlocal seen
            await message.ack()
            seen += 1
            if seen == count:
                done.set()

        started = time.perf_counter()
        await source.consume(on_message)
        await asyncio.wait_for(done.wait(), 600)
        return count / (time.perf_counter() - started)


def raw_rates(admin_url: str, count: int, size: int = SIZE) -> Figures:
    """Raw publish and consume of ``count`` messages of ``size`` bytes, in a queue like the ingest's."""
    declare_queue(admin_url, ingest_queue_arguments())
    return {
        "publish msg/s": raw_publish(admin_url, count, size),
        "consume msg/s": asyncio.run(raw_consume(admin_url, count)),
    }


def figures(context: Context) -> Figures:
    """The suite's baseline: raw rates into a quorum queue declared like fleetbus's ingest queue."""
    count = context.size(20_000, 5_000)
    context.show(f"{count:,} messages of {SIZE} bytes")
    with context.vhost() as admin_url:
        return raw_rates(admin_url, count)
