"""`fleetbus replay` of a long window: its resident memory must not grow with the window.

    .venv/bin/python -m bench --only replay [--quick]
    .venv/bin/python -m bench.replay --messages 1000000

The recording is written straight into the run's SQLite recording (status events of about 480
bytes, one a millisecond, through the recording store's own ``write_recorded``), since the point is
the replay, not the recorder. Then `fleetbus replay --speed 0` sends the whole window to an
exchange of the run's own (its one queue keeps the newest 1,000, so the broker holds no more),
as a process of its own whose resident memory is sampled from /proc, and its report must say that
every message was published.

The suite's 50,000 messages are a window a replay could not hold in memory and stay under the
150 MB target: one that read its whole window first took 400 MB for 100,000 of these messages
(about 4 KB each once read), so this window would be about 200 MB on top of the process's 70 MB.
Fewer keep the suite short: the recording is written first, and `fleetbus replay` (up to 1,024
messages awaiting their confirms) sends 3,000 to 4,000 messages a second on 2 cores.
``--messages 1000000`` runs the long window by hand.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import datetime, timedelta, timezone

from bench.proc import rss_megabytes
from bench.scenario import Context, Figures
from bench.worker_memory import SAMPLE_EVERY, peak_megabytes
from fleetbus.publishers.tls import blocking_connection
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.recordings import RecordedMessage
from tests.factories import status
from tests.support import Bus

EXCHANGE = "bench.replay"
ROBOT = "bench-replay"
WRITE_BATCH = 10_000
MESSAGES = 50_000
T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)


def recorded_status(i: int) -> RecordedMessage:
    body = {
        "message_id": f"00000000-0000-4000-8000-{i:012d}",
        "robot_id": ROBOT,
        "seq": i,
        "sent_at": (T0 + timedelta(milliseconds=i)).isoformat(),
        "schema_version": 1,
        "type": "status",
        "body": {**status(80), "current_waypoint": "corridor-east-" + "x" * 180},
    }
    size = len(json.dumps(body))
    return RecordedMessage(
        key=f"{ROBOT}:{i}",
        type="status",
        recorded_at=T0 + timedelta(milliseconds=i),
        exchange=f"{ROBOT}.events",
        routing_key=f"{ROBOT}.status",
        user_id=ROBOT,
        robot_id=ROBOT,
        message_id=body["message_id"],
        seq=i,
        known=True,
        document=body,
        properties={"message_id": body["message_id"], "content_type": "application/json"},
        size=size,
    )


def write_recording(bus: Bus, count: int, show: Callable[[str], None]) -> None:
    async def write() -> None:
        async with open_recording_store(bus.settings) as store:
            for start in range(0, count, WRITE_BATCH):
                await store.write_recorded(
                    [recorded_status(i) for i in range(start, min(count, start + WRITE_BATCH))]
                )
                show(f"recording {count:,} messages: {start + WRITE_BATCH:,}")

    asyncio.run(write())


def declare_target(admin_url: str) -> None:
    """The exchange replayed into, and a queue that keeps only the newest 1,000 (so all are routable)."""
    connection = blocking_connection(admin_url)
    try:
        channel = connection.channel()
        channel.exchange_declare(EXCHANGE, "topic", durable=True)
        channel.queue_declare(EXCHANGE, durable=True, arguments={"x-max-length": 1000})
        channel.queue_bind(EXCHANGE, EXCHANGE, "#")
    finally:
        connection.close()


def replay_process(bus: Bus, count: int, show: Callable[[str], None]) -> dict[str, float]:
    until = (T0 + timedelta(milliseconds=count)).isoformat()
    args = ["replay", "--to", EXCHANGE, "--since", T0.isoformat(), "--until", until, "--speed", "0", "--json"]
    # to a file: a report larger than a pipe's buffer would block the process before it ends
    out_path = bus.settings.data_dir / "replay.json"
    with out_path.open("w") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "fleetbus", *args],
            env=bus.worker_env(),
            stdout=out,
            stderr=subprocess.DEVNULL,
        )
    samples: list[float] = []
    peak = 0.0
    started = time.monotonic()
    while process.poll() is None:
        try:
            resident, high = rss_megabytes(process.pid), peak_megabytes(process.pid)
        except (FileNotFoundError, ProcessLookupError):
            break  # it ended between the poll and the read
        if not resident:
            break  # ended: a process that has exited has no resident memory left to read
        samples.append(resident)
        peak = max(peak, high)
        show(f"replaying {count:,} messages: {samples[-1]:.0f} MB resident")
        time.sleep(SAMPLE_EVERY)  # the sampling interval of the measurement
    process.wait()
    elapsed = time.monotonic() - started
    if process.returncode != 0:
        raise RuntimeError(f"fleetbus replay exited with {process.returncode}")
    report = json.loads(out_path.read_text().strip().splitlines()[-1])
    if report["published"] != count:
        raise AssertionError(f"replay published {report['published']:,} of {count:,} messages: {report}")
    return {
        "replay RSS MB, peak": max(peak, max(samples, default=0.0)),
        "replay RSS MB, median": sorted(samples)[len(samples) // 2] if samples else 0.0,
        "replay msg/s": count / elapsed,
        "messages": float(count),
    }


def measure(context: Context, count: int) -> Figures:
    with context.bus() as bus:
        write_recording(bus, count, context.show)
        declare_target(bus.admin_url)
        return replay_process(bus, count, context.show)


def figures(context: Context) -> Figures:
    return measure(context, context.size(MESSAGES, MESSAGES // 5))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=1_000_000)
    options = parser.parse_args()
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.settings import load_settings
    from fleetbus_dev.fallback import resolve_broker

    endpoint = resolve_broker(load_settings(), start=True)
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        result = measure(
            Context(endpoint, api, show=lambda text: print(text, file=sys.stderr, end="\r")), options.messages
        )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
