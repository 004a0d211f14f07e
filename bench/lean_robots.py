"""Many robots in one asyncio process, each speaking the AMQP contract itself: a fleet's traffic at
a fraction of the cost of a ``RobotClient`` per robot.

    python -m bench.lean_robots RATE URLS_FILE

Each line of URLS_FILE (mode 0600) is a robot's account. Each robot opens its own connection (its
login is the ``user_id`` the broker checks) and publishes its share of RATE status events a second
to its events exchange, persistent, with the properties and envelope a ``RobotClient`` gives them
(:func:`fleetbus.publishers.client.outgoing`), and awaits each publisher confirm. It keeps no
outbox: what this measures is the server's side of a large fleet, on a machine whose two cores
cannot also run a thousand robot processes (a ``RobotClient`` costs about 0.16 % of a core at one
event a second, mostly its threads; 1,000 of them left nothing for the broker). The process
prints ``publishing`` once every robot is connected, runs until its standard input closes, then
prints one JSON line: ``{"published": N, "seconds": S}``, N the events confirmed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import time
from pathlib import Path
from urllib.parse import unquote, urlsplit

import aio_pika

from bench.ingest import status_items
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import EventType, event_routing_key, events_exchange

CONNECT_TRIES = 20


async def connect(url: str) -> aio_pika.abc.AbstractRobustConnection | aio_pika.abc.AbstractConnection:
    for attempt in range(CONNECT_TRIES):
        try:
            return await aio_pika.connect(url, timeout=30)
        except (aio_pika.exceptions.AMQPConnectionError, asyncio.TimeoutError, ConnectionError):
            await asyncio.sleep(random.uniform(0, min(10.0, 0.5 * 2**attempt)))  # full jitter
    raise RuntimeError(f"could not connect after {CONNECT_TRIES} tries")


async def robot(url: str, rate: float, stop: asyncio.Event, connected: asyncio.Queue[None]) -> int:
    name = unquote(urlsplit(url).username or "")
    connection = await connect(url)
    await connected.put(None)
    channel = await connection.channel(publisher_confirms=True)
    exchange = await channel.get_exchange(events_exchange(name), ensure=False)
    epoch, body = new_epoch(), status_items(1)[0][1]
    period = 1 / rate
    published = 0
    try:
        await asyncio.wait_for(stop.wait(), random.uniform(0, period))  # a random phase
    except asyncio.TimeoutError:
        pass
    started = time.monotonic()
    while not stop.is_set():
        event = build_event(EventType.STATUS, name, epoch, published, body)
        message = aio_pika.Message(
            encode_event(event),
            content_type="application/json",
            delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
            message_id=str(event.message_id),
            user_id=name,
            timestamp=event.sent_at,
            type=EventType.STATUS.value,
            app_id="fleetbus-robot",
        )
        await exchange.publish(message, event_routing_key(name, EventType.STATUS))  # confirmed
        published += 1
        due = started + published * period - time.monotonic()
        if due > 0:
            try:
                await asyncio.wait_for(stop.wait(), due)
            except asyncio.TimeoutError:
                pass
    await connection.close()
    return published


async def run(rate: float, urls: list[str]) -> None:
    stop = asyncio.Event()
    connected: asyncio.Queue[None] = asyncio.Queue()
    each = rate / len(urls)
    tasks = [asyncio.create_task(robot(url, each, stop, connected)) for url in urls]
    for _ in urls:
        getter = asyncio.create_task(connected.get())
        done, _pending = await asyncio.wait({getter, *tasks}, return_when=asyncio.FIRST_COMPLETED)
        failed = [t for t in done if t is not getter and t.exception()]
        if failed:
            raise failed[0].exception()  # type: ignore[misc]
        await getter
    print("publishing", flush=True)
    started = time.monotonic()
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    stop.set()
    published = sum(await asyncio.gather(*tasks))
    print(json.dumps({"published": published, "seconds": time.monotonic() - started}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rate", type=float, help="events a second, all robots together")
    parser.add_argument("urls", type=Path, help="a file of the robots' AMQP URLs, one a line")
    args = parser.parse_args()
    asyncio.run(run(args.rate, args.urls.read_text().split()))


if __name__ == "__main__":
    main()
