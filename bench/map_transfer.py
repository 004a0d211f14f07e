"""Map transfer: a 4000 x 4000 PGM (16 MB) from the explorer's publish until a warden holds it, identical.

    .venv/bin/python -m bench --only map [--runs 3]

The explorer publishes the map as robot code does (``publish_map``: chunk events, then the map
event, through its outbox with pipelined confirms); `fleetbus worker` stores and checks it and
notifies the wardens; the warden, on its notification, fetches the version over the
request/reply service chunk by chunk, and the bytes and YAML fields are compared with what was
sent. The image is random bytes (a fresh seed each run), so a chunk out of place cannot pass.

For reference, the same 16 MB goes through the raw broker in the same run: published as
persistent messages of the map's chunk size (pipelined confirms) into a queue declared like the
ingest queue, then consumed.
"""

from __future__ import annotations

import asyncio
import random
import sys
import time

from bench.processes import worker_process
from bench.raw import RAW_QUEUE, declare_queue, ingest_queue_arguments, publish_bodies, raw_consume
from bench.scenario import Context, Figures
from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.routing import RobotKind, Topic
from fleetbus_dev.demo import MAP_YAML

SIDE = 4000


def random_pgm(side: int, seed: int) -> bytes:
    return f"P5\n{side} {side}\n255\n".encode() + random.Random(seed).randbytes(side * side)


def raw_transfer(context: Context, image: bytes) -> float:
    """Seconds to publish ``image`` in chunks through the raw broker and consume them all."""
    chunks = [image[i : i + MAP_CHUNK_BYTES] for i in range(0, len(image), MAP_CHUNK_BYTES)]
    with context.vhost() as admin_url:
        declare_queue(admin_url, ingest_queue_arguments())
        started = time.monotonic()
        publish_bodies(admin_url, "", RAW_QUEUE, chunks)
        asyncio.run(raw_consume(admin_url, len(chunks)))
        return time.monotonic() - started


def figures(context: Context) -> Figures:
    image = random_pgm(SIDE, random.randrange(2**32))
    context.show(f"{len(image) / 1e6:.0f} MB through the raw broker")
    raw = raw_transfer(context, image)
    with context.bus() as bus:
        explorer = bus.robot(bus.add("bench-explorer", kind=RobotKind.EXPLORER))
        warden = bus.robot(bus.add("bench-warden", kind=RobotKind.WARDEN))
        with worker_process(bus, "--no-recorder"):
            context.show(f"a {SIDE} x {SIDE} map ({len(image) / 1e6:.0f} MB) from explorer to warden")
            started = time.monotonic()
            explorer.publish_map(image, MAP_YAML)
            published = time.monotonic()
            notes = warden.receive(1, timeout=60)
            notified = time.monotonic()
            if not notes or notes[0].topic is not Topic.MAP or notes[0].map_version is None:
                raise RuntimeError(f"the warden got {notes!r} instead of a map notification")
            fetched = warden.fetch_map(notes[0].map_version, timeout=30)
            done = time.monotonic()
    if fetched.pgm != image or any(fetched.metadata[key] != value for key, value in MAP_YAML.items()):
        raise RuntimeError(f"map version {fetched.version} arrived different from what was sent")
    return {
        "transfer s": done - started,
        "explorer's publish s": published - started,
        "until notified s": notified - started,
        "warden's fetch s": done - notified,
        "raw broker s": raw,
    }


if __name__ == "__main__":
    from bench.suite import main

    sys.exit(main(["--only", "map", *sys.argv[1:]]))
