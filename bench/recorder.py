"""The recorder under the reference's logger benchmark: 100 messages a second of 480 bytes.

    .venv/bin/python -m bench.recorder [--seconds 30] [--runs 3] [--backlog 20000] [--against main]

Each run, in a fresh virtual host and data folder:

  raw broker     pika publishes 10,000 persistent 480-byte messages (pipelined confirms) into a
                 durable classic queue, then aio-pika consumes them: the broker's own rate, now
  100 msg/s      ``fleetbus recorder run`` as a process of its own (SQLite store); a robot
                 publishes 480-byte messages at 100 a second, each confirmed, for --seconds; the
                 recorder's CPU (user + system time over wall time, % of one core) and resident
                 memory are read from /proc every half second (VmRSS: mean, steady = median of the
                 second half, peak; and VmHWM, the kernel's peak since the process started), and
                 the broker's CPU likewise when it is the private node. With --against REF, that
                 commit's recorder does the same in each run, before or after today's at random
  backlog        --backlog messages queued while the recorder is stopped, then it starts: its
                 top rate (how much room there is above 100 a second)

Medians and spreads (min-max) over the runs are printed and written to bench/results/.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pika
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.baseline import baseline_tree, commit_of
from bench.proc import Watch, rss_megabytes
from bench.processes import FleetbusProcess
from bench.raw import declare_queue, raw_consume, raw_publish
from bench.results import medians, save, spread
from bench.scenario import Context, Figures
from fleetbus.broker.accounts import Account, Role, fresh_vhost, provision_account
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.urls import without_password
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RECORDER_QUEUE, events_exchange
from fleetbus.settings import Settings, load_settings
from fleetbus.workers.setup import set_up_service
from fleetbus.workers.store.sqlite_recordings import SQLiteRecordingStore
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode
from tests.support import wait_for

VHOST = "fleetbus-bench-recorder"
ROBOT = "bench-recorder"
SIZE = 480
RATE = 100
console = Console()


def body(i: int) -> bytes:
    """A transform as JSON, padded to exactly SIZE bytes."""
    doc = {"frame": "/kinect/depth", "child_frame": "/object/bottle", "i": i, "translation": [0.1, 0.2, 0.3]}
    doc["pad"] = ""
    doc["pad"] = "x" * (SIZE - len(json.dumps(doc)))
    data = json.dumps(doc).encode()
    assert len(data) == SIZE
    return data


def properties(i: int) -> pika.BasicProperties:
    return pika.BasicProperties(
        delivery_mode=2, user_id=ROBOT, content_type="application/json", message_id=f"bench-{i}"
    )


def paced(account: Account, seconds: float, first: int) -> int:
    """Publish RATE messages a second, each confirmed, on an absolute schedule; how many."""
    connection = blocking_connection(account.amqp_url)
    channel = connection.channel()
    channel.confirm_delivery()
    count = int(RATE * seconds)
    start = time.monotonic()
    for i in range(count):
        delay = start + i / RATE - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        channel.basic_publish(events_exchange(ROBOT), f"{ROBOT}.tf", body(first + i), properties(first + i))
    connection.close()
    return count


def backlog(account: Account, count: int, first: int) -> None:
    connection = blocking_connection(account.amqp_url)
    confirms = PipelinedConfirms(connection, connection.channel(), timeout=120)
    for start in range(0, count, 1000):
        confirms.publish(
            [
                Outgoing(events_exchange(ROBOT), f"{ROBOT}.tf", body(i), properties(i))
                for i in range(first + start, first + min(count, start + 1000))
            ],
            120,
        )
    connection.close()


def recorded(settings: Settings) -> int:
    async def count() -> int:
        async with SQLiteRecordingStore(settings.recording_path) as store:
            return (await store.type_summary("tf")).records

    return asyncio.run(count()) if settings.recording_path.exists() else 0


def recorder_process(
    settings: Settings, endpoint: BrokerEndpoint, admin_url: str, code: Path | None = None
) -> FleetbusProcess:
    """``python -m fleetbus recorder run`` against the run's vhost and data folder, as
    ``fleetbus-recorder`` alone (``fleetbus setup`` first, as the administrator); ``code``: a
    :func:`bench.baseline.baseline_tree` to run an earlier commit's recorder instead of today's."""
    service = asyncio.run(set_up_service(settings, replace(endpoint, amqp_url=admin_url)))
    env = {
        **os.environ,
        "FLEETBUS_SERVICE_URL": without_password(service.service_url),
        "FLEETBUS_DATA_DIR": str(settings.data_dir),
    }
    if code is not None:
        # PYTHONSAFEPATH: the working folder (this checkout) must not come before ``code``
        env.update(PYTHONPATH=str(code), PYTHONSAFEPATH="1")
    for unused in ("FLEETBUS_AMQP_URL", "FLEETBUS_MANAGEMENT_URL", "FLEETBUS_MONGODB_URL"):
        env.pop(unused, None)
    log = settings.data_dir / "recorder.log"
    return FleetbusProcess(["recorder", "run"], env, log, admin_url, RECORDER_QUEUE)


def recording_at_rate(
    endpoint: BrokerEndpoint, admin_url: str, account: Account, seconds: float, code: Path | None
) -> dict[str, float]:
    """The recorder (today's, or ``code``'s) in a fresh data folder while a robot publishes RATE a
    second for ``seconds``: its CPU share and resident memory; the broker's CPU when it is ours."""
    broker_pid = LocalNode(load_settings().broker_dir).pid() if endpoint.kind == "private" else None
    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        settings = load_settings().updated(data_dir=Path(tmp), amqp_url=admin_url, mongodb_url=None)
        with recorder_process(settings, endpoint, admin_url, code) as recorder:
            pids = {"recorder": recorder.pid, **({"broker": broker_pid} if broker_pid else {})}
            watch = Watch(pids)
            published: list[int] = []
            cpu = watch.measure(lambda: published.append(paced(account, seconds, 0)))
            started = time.monotonic()
            wait_for(lambda: recorded(settings) >= published[0], 120, "the paced messages to be recorded")
            result["lag after the last, s"] = time.monotonic() - started
            result["recorder RSS MB, VmHWM"] = rss_megabytes(recorder.pid, "VmHWM")
        samples = watch.rss["recorder"]
        result["recorder CPU %"] = cpu["recorder"]
        result["recorder RSS MB, mean"] = statistics.fmean(samples)
        result["recorder RSS MB, steady"] = statistics.median(samples[len(samples) // 2 :])
        result["recorder RSS MB, peak"] = max(samples)
        if broker_pid:
            result["broker CPU %"] = cpu["broker"]
    return result


def one_run(
    endpoint: BrokerEndpoint,
    api: ManagementAPI,
    seconds: float,
    backlog_size: int,
    baseline: tuple[str, Path] | None = None,
) -> dict[str, float]:
    """One run: the raw broker, the recorder at RATE (and ``baseline``'s, named, in the same run,
    in alternating order), then the backlog."""
    admin_url = fresh_vhost(api, endpoint.amqp_url, VHOST)
    result: dict[str, float] = {}
    declare_queue(admin_url, {"x-queue-type": "classic"})
    result["raw publish msg/s"] = raw_publish(admin_url, 10_000, SIZE)
    result["raw consume msg/s"] = asyncio.run(raw_consume(admin_url, 10_000))
    account = asyncio.run(provision_account(admin_url, api, ROBOT, Role.ROBOT, rotate=True))
    variants: list[tuple[str, Path | None]] = [("", None)]
    if baseline is not None:
        name, code = baseline
        variants.append((f"{name}: ", code))
        if random.random() < 0.5:
            variants.reverse()
    for prefix, code in variants:
        for key, value in recording_at_rate(endpoint, admin_url, account, seconds, code).items():
            result[prefix + key] = value
    if backlog_size:
        with tempfile.TemporaryDirectory() as tmp:
            settings = load_settings().updated(data_dir=Path(tmp), amqp_url=admin_url, mongodb_url=None)
            backlog(account, backlog_size, 0)
            started = time.monotonic()
            with recorder_process(settings, endpoint, admin_url):
                wait_for(lambda: recorded(settings) >= backlog_size, 600, "the backlog to be recorded")
                result["backlog msg/s (process start included)"] = backlog_size / (time.monotonic() - started)
    api.delete_user(ROBOT)
    api.delete_vhost(VHOST)
    return result


def figures(context: Context) -> Figures:
    """The suite's recorder: the logger benchmark's rate, and its top rate on a backlog."""
    seconds, backlog_size = context.size(30, 10), context.size(20_000, 5_000)
    context.show(f"{RATE} msg/s of {SIZE} bytes for {seconds} s, then a backlog of {backlog_size:,}")
    return one_run(context.endpoint, context.api, seconds, backlog_size)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=30)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--backlog", type=int, default=20000, help="0: no backlog phase")
    parser.add_argument(
        "--against",
        metavar="REF",
        help="also run this commit's recorder (e.g. main) in each run, in alternating order",
    )
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    runs: list[dict[str, float]] = []
    loads: list[float] = []
    with contextlib.ExitStack() as stack:
        baseline = None
        if args.against:
            baseline = (commit_of(args.against), stack.enter_context(baseline_tree(args.against)))
        api = stack.enter_context(ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url))
        progress = stack.enter_context(Progress(console=console, transient=True))
        task = progress.add_task(f"{args.runs} runs", total=args.runs)
        for _ in range(args.runs):
            runs.append(one_run(endpoint, api, args.seconds, args.backlog, baseline))
            loads.append(os.getloadavg()[0])
            progress.advance(task)
    table = Table(
        title=f"the recorder at {RATE} msg/s of {SIZE} bytes for {args.seconds:g} s; {args.runs} runs; "
        f"load average after each: {', '.join(f'{load:.1f}' for load in loads)}"
    )
    table.add_column("measure")
    table.add_column("median", justify="right")
    table.add_column("spread", justify="right")
    middle = medians(runs)
    for key, median in middle.items():
        table.add_row(key, f"{median:,.1f}", spread(runs, key, 1))
    console.print(table)
    path = save(
        args.out,
        "recorder",
        {"seconds": args.seconds, "against": args.against, "load": loads, "runs": runs, "medians": middle},
    )
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
