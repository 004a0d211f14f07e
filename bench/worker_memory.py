"""Worker resident memory over 200,000 events: it must not grow with the number of events.

    .venv/bin/python -m bench --only memory [--quick]

A robot's account publishes the events first, fast: valid status events (its own ``user_id``,
exchange and routing key, exactly the properties its client sets) with pipelined confirms and
no outbox, since the point is the worker, not the robot. Then `fleetbus worker --no-recorder`
starts and drains the queue while its resident memory is sampled from /proc, with how many
events it has taken so far. Growth is measured between a tenth of the events and the end
(20,000 and 200,000; with ``--quick``, 2,000 and 20,000); at the end every event must be stored
once, the queue empty and nothing dead-lettered.

The target is flat growth, so the number of events only has to be large enough for a leak to
show: over the 180,000 events after the first tenth, a leak of 50 bytes an event adds 9 MB, more
than a tenth of the worker's 75 MB. A million events took three and a half minutes on a quiet
machine, for the same verdict.
"""

from __future__ import annotations

import sys
import time
import uuid
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from bench.ingest import status_items, stored_and_acked
from bench.proc import rss_megabytes
from bench.processes import worker_process
from bench.raw import WINDOW
from bench.scenario import Context, Figures
from fleetbus.publishers.client import outgoing
from fleetbus.publishers.confirms import PipelinedConfirms
from fleetbus.publishers.outbox import Entry
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch, parse_event
from fleetbus.schemas.routing import INGEST_QUEUE, EventType
from tests.support import Bus, wait_for

ROBOT = "bench-memory"
EVENTS = 200_000
SAMPLE_EVERY = 0.5


def event_renderer(robot: str, epoch: str) -> Callable[[int, str], bytes]:
    """Status events of ``epoch`` as JSON for any (seq, message id), from one event pydantic encoded."""
    marker_id, marker_seq = uuid.UUID(int=0), 987_654_321_987
    event_type, body = status_items(1)[0]
    sample = encode_event(build_event(event_type, robot, epoch, marker_seq, body, message_id=marker_id))
    head, rest = sample.split(str(marker_id).encode())
    middle, tail = rest.split(str(marker_seq).encode())

    def render(seq: int, message_id: str) -> bytes:
        return b"".join((head, message_id.encode(), middle, str(seq).encode(), tail))

    checked = parse_event(render(7, str(uuid.uuid4())))
    assert checked.seq == 7 and checked.robot_id == robot, "the template renders other events"
    return render


def prefill(url: str, robot: str, count: int, show: Callable[[str], None]) -> float:
    """Publish ``count`` events as ``robot`` (pipelined confirms); events a second."""
    epoch = new_epoch()  # one run of a robot, as a client's start makes
    render = event_renderer(robot, epoch)
    sent_at = datetime.now(timezone.utc)
    connection = blocking_connection(url)
    try:
        confirms = PipelinedConfirms(connection, connection.channel(), timeout=120)
        started = time.perf_counter()
        for start in range(0, count, WINDOW):
            window = []
            for seq in range(start, min(count, start + WINDOW)):
                message_id = str(uuid.uuid4())
                entry = Entry(
                    epoch, seq, EventType.STATUS.value, message_id, sent_at, render(seq, message_id), (0, 0)
                )
                window.append(outgoing(robot, entry))
            confirms.publish(window, 120)
            if start % (50 * WINDOW) == 0:
                show(f"queueing {count:,} events: {start:,}")
        return count / (time.perf_counter() - started)
    finally:
        if connection.is_open:
            connection.close()


def peak_megabytes(pid: int) -> float:
    """The process's resident high-water mark (VmHWM)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return 0.0


def drain(bus: Bus, count: int, show: Callable[[str], None]) -> dict[str, float]:
    """Start the worker on ``count`` queued events; its memory along the way, until all are stored."""
    samples: list[tuple[int, float]] = []  # (events taken, resident MB)
    with worker_process(bus, "--no-recorder") as worker:
        started = time.monotonic()
        deadline = started + 600 + count / 500
        while True:
            waiting = bus.ready_messages(INGEST_QUEUE)
            samples.append((count - waiting, rss_megabytes(worker.pid)))
            show(f"worker drained {count - waiting:,} of {count:,}: {samples[-1][1]:.0f} MB resident")
            if waiting == 0:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"{waiting:,} of {count:,} events still queued")
            time.sleep(SAMPLE_EVERY)  # the sampling interval of the measurement
        wait_for(lambda: bus.count(EventType.STATUS.value) >= count, 600, f"{count:,} stored", interval=0.5)
        elapsed = time.monotonic() - started
        end, peak = rss_megabytes(worker.pid), peak_megabytes(worker.pid)
    warm = next(rss for taken, rss in samples if taken >= count // 10)
    return {
        "RSS MB at a tenth": warm,
        "RSS MB at the end": end,
        "peak RSS MB": peak,
        "growth %": 100 * (end - warm) / warm,
        "drain msg/s": count / elapsed,
    }


def figures(context: Context) -> Figures:
    count = context.size(EVENTS, EVENTS // 10)
    with context.bus() as bus:
        account = bus.add(ROBOT)
        result = {
            "events": float(count),
            "queueing msg/s": prefill(account.amqp_url, ROBOT, count, context.show),
        }
        wait_for(lambda: bus.ready_messages(INGEST_QUEUE) >= count, 120, f"{count:,} events queued")
        result.update(drain(bus, count, context.show))
        stored_and_acked(bus, count)
    return result


if __name__ == "__main__":
    from bench.suite import main

    sys.exit(main(["--only", "memory", *sys.argv[1:]]))
