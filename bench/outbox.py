"""The robot's outbox: append time as it fills, and how fast it drains after an outage.

    .venv/bin/python -m bench.outbox [--waiting 0,10000,50000] [--appends 300] [--drain 10000] [--runs 3]
                                     [--windows 1000x2,1024x4]

append   one event appended (and fsynced) to an outbox that already holds N waiting events;
         median and 99th percentile over ``--appends`` appends, for each N
drain    ``--drain`` events wait in a robot's outbox (the broker was away); the robot starts and
         the time until the broker confirmed them all gives the drain rate, next to the raw broker
         publish rate (pika, pipelined confirms, same message size) measured in the same run;
         with ``--windows``, one drain per sender setting (events per window x windows in flight,
         e.g. the old 1000x2 against today's) in each run, in random order with the raw publish
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import statistics
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.ingest import BENCH_VHOST, status_items
from bench.raw import SIZE, declare_queue, ingest_queue_arguments, raw_publish
from bench.results import percentile, save
from bench.scenario import Context, Figures
from fleetbus.broker.accounts import Role, fresh_vhost, provision_account
from fleetbus.broker.management import ManagementAPI
from fleetbus.publishers import sender
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.outbox import Outbox, Overflow, TypePolicy
from fleetbus.schemas.envelope import build_event, new_epoch
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker

ROBOT = "bench-outbox"
WAITING = (0, 10_000, 50_000)
console = Console()
#: Nothing dropped, whatever the fill: the benchmark measures appends, not the overflow policy.
KEEP_ALL = {"status": TypePolicy(Overflow.KEEP, 10_000_000)}


def append_times(waiting: int, appends: int) -> list[float]:
    """Seconds per single-event append into an outbox already holding ``waiting`` events."""
    (event_type, body) = status_items(1)[0]
    epoch = new_epoch()
    with tempfile.TemporaryDirectory() as folder:
        outbox = Outbox(Path(folder), KEEP_ALL)
        for start in range(0, waiting, 1000):
            n = min(1000, waiting - start)
            outbox.append([build_event(event_type, "bench", epoch, start + i, body) for i in range(n)])
        times = []
        for i in range(appends):
            event = build_event(event_type, "bench", epoch, waiting + i, body)
            started = time.perf_counter()
            outbox.append([event])
            times.append(time.perf_counter() - started)
        outbox.close()
    return times


def drain_rate(robot_url: str, count: int, size: int = SIZE) -> float:
    """Events a second confirmed by the broker from a robot that starts with ``count`` waiting."""
    with tempfile.TemporaryDirectory() as folder:
        robot = RobotClient(robot_url, state_dir=Path(folder), outbox_policies=KEEP_ALL)
        items = status_items(count, size)
        for start in range(0, count, 1000):  # queued while the robot is not started: an outage
            robot.outbox.append(robot.build(items[start : start + 1000]))
        started = time.perf_counter()
        robot.start()
        if not robot.flush(600):
            raise TimeoutError(f"{robot.outbox.pending()} events still waiting")
        elapsed = time.perf_counter() - started
        robot.close()
    return count / elapsed


def figures(context: Context) -> Figures:
    """The suite's outbox: append times as it fills, and the drain after an outage."""
    appends, drain = context.size(300, 100), context.size(10_000, 5_000)
    result: Figures = {}
    for waiting in WAITING:
        context.show(f"{appends} appends at {waiting:,} waiting events")
        ms = [1000 * seconds for seconds in append_times(waiting, appends)]
        result[f"append ms at {waiting:,}, median"] = statistics.median(ms)
        result[f"append ms at {waiting:,}, p99"] = percentile(ms, 99)
    context.show(f"draining {drain:,} events that waited out an outage")
    with context.bus() as bus:
        result["drain msg/s"] = drain_rate(bus.add(ROBOT).amqp_url, drain)
    return result


def parse_windows(text: str) -> dict[str, tuple[int, int]]:
    """``1000x2,1024x4`` -> {name: (events per window, windows in flight)}."""
    settings = {}
    for item in text.split(","):
        window, _, in_flight = item.partition("x")
        settings[item] = (int(window), int(in_flight))
    return settings


def compare_windows(
    admin_url: str, robot_url: str, count: int, windows: dict[str, tuple[int, int]]
) -> dict[str, float]:
    """The raw publish and one drain per sender setting, in random order: msg/s of each."""
    today = (sender.PUBLISH_WINDOW, sender.WINDOWS_IN_FLIGHT)
    order = ["raw publish", *windows]
    random.shuffle(order)
    rates = {}
    try:
        for name in order:
            if name == "raw publish":
                rates[name] = raw_publish(admin_url, count, SIZE)
                continue
            sender.PUBLISH_WINDOW, sender.WINDOWS_IN_FLIGHT = windows[name]
            rates[name] = drain_rate(robot_url, count)
    finally:
        sender.PUBLISH_WINDOW, sender.WINDOWS_IN_FLIGHT = today
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--waiting", default=",".join(map(str, WAITING)))
    parser.add_argument("--appends", type=int, default=300)
    parser.add_argument("--drain", type=int, default=10000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument(
        "--windows",
        help="compare drains with these sender settings, WINDOWxIN_FLIGHT[,...] (no append figures)",
    )
    args = parser.parse_args()
    if args.windows:
        windows_main(args.windows, args.drain, args.runs, args.out)
        return
    fills = [int(n) for n in args.waiting.split(",")]
    endpoint = resolve_broker(load_settings(), start=True)
    appends: dict[int, list[float]] = {n: [] for n in fills}
    drains: list[float] = []
    raws: list[float] = []
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        Progress(console=console) as progress,
    ):
        task = progress.add_task("outbox", total=args.runs * (len(fills) + 2))
        for _ in range(args.runs):
            for n in fills:
                appends[n] += append_times(n, args.appends)
                progress.advance(task)
            admin_url = fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST)
            declare_queue(admin_url, ingest_queue_arguments())
            raws.append(raw_publish(admin_url, args.drain, SIZE))
            progress.advance(task)
            account = asyncio.run(provision_account(admin_url, api, ROBOT, Role.ROBOT, rotate=True))
            drains.append(drain_rate(account.amqp_url, args.drain))
            progress.advance(task)
            api.delete_user(ROBOT)
            api.delete_vhost(BENCH_VHOST)
    table = Table(title=f"outbox append, {args.runs} runs of {args.appends} appends (fsync on)")
    for column in ("events waiting", "median ms", "p99 ms", "max ms"):
        table.add_column(column, justify="right")
    summary: dict[str, object] = {"appends": {}, "drain": drains, "raw_publish": raws}
    for n, times in appends.items():
        ms = sorted(t * 1000 for t in times)
        p99 = percentile(ms, 99)
        table.add_row(f"{n:,}", f"{statistics.median(ms):.2f}", f"{p99:.2f}", f"{ms[-1]:.2f}")
        summary["appends"][n] = {"median_ms": statistics.median(ms), "p99_ms": p99}  # type: ignore[index]
    console.print(table)
    drain, raw = statistics.median(drains), statistics.median(raws)
    rates = Table(title=f"drain of {args.drain:,} waiting events of {SIZE} bytes, {args.runs} runs")
    for column in ("scenario", "median msg/s", "spread", "vs raw publish"):
        rates.add_column(column, justify="left" if column == "scenario" else "right")
    rates.add_row(
        "raw publish (pika, pipelined confirms)", f"{raw:,.0f}", f"{min(raws):,.0f}-{max(raws):,.0f}", "1.00"
    )
    rates.add_row(
        "outbox drain", f"{drain:,.0f}", f"{min(drains):,.0f}-{max(drains):,.0f}", f"{drain / raw:.2f}"
    )
    console.print(rates)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"outbox-{datetime.now(timezone.utc):%Y%m%dT%H%M%S}.json"
    path.write_text(json.dumps(summary, indent=2))
    console.print(f"wrote {path}")


def windows_main(text: str, count: int, runs_wanted: int, out: Path) -> None:
    windows = parse_windows(text)
    endpoint = resolve_broker(load_settings(), start=True)
    runs: list[dict[str, float]] = []
    loads: list[float] = []
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        for _ in range(runs_wanted):
            admin_url = fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST)
            declare_queue(admin_url, ingest_queue_arguments())
            account = asyncio.run(provision_account(admin_url, api, ROBOT, Role.ROBOT, rotate=True))
            runs.append(compare_windows(admin_url, account.amqp_url, count, windows))
            loads.append(os.getloadavg()[0])
            api.delete_user(ROBOT)
            api.delete_vhost(BENCH_VHOST)
    raw = [run["raw publish"] for run in runs]
    table = Table(
        title=f"drain of {count:,} waiting events, {runs_wanted} runs; "
        f"load average after each: {', '.join(f'{load:.1f}' for load in loads)}"
    )
    for column in ("sender setting", "median msg/s", "spread", "median / raw median", "median of ratios"):
        table.add_column(column, justify="left" if column == "sender setting" else "right")
    summary: dict[str, object] = {"runs": runs, "load": loads, "ratios": {}}
    for name in ["raw publish", *windows]:
        rates = [run[name] for run in runs]
        ratio = statistics.median(rates) / statistics.median(raw)
        per_run = statistics.median(run[name] / run["raw publish"] for run in runs)
        summary["ratios"][name] = {"of medians": ratio, "median of ratios": per_run}  # type: ignore[index]
        table.add_row(
            name,
            f"{statistics.median(rates):,.0f}",
            f"{min(rates):,.0f}-{max(rates):,.0f}",
            f"{ratio:.2f}",
            f"{per_run:.2f}",
        )
    console.print(table)
    path = save(out, "outbox-windows", summary)
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
