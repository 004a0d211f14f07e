"""A fleet of hundreds on one broker node: provisioning, the cost per robot, hazards, the views.

    .venv/bin/python -m bench.fleet [--robots 100,300,1000] [--seconds 30] [--hazards 40]

For each fleet size, in a virtual host and store of its own:

- **provisioning**: ``fleetbus users add-many`` makes every robot's account (and an explorer's
  and a warden's), timed as an operator runs it;
- **the fleet**: every robot a real ``RobotClient`` publishing a status event a second (confirmed),
  ``--per-process`` robots (125) to a process (:mod:`bench.telemetry`); with ``--lean``, robots that
  speak the AMQP contract themselves, 500 to an asyncio process (:mod:`bench.lean_robots`: a
  ``RobotClient`` per robot costs this 2-core machine more than the broker and the workers do);
  the robots' processes run at ``--nice`` (15: on what the server leaves, as robots elsewhere);
  the workers (``fleetbus worker --no-recorder``, as many and with as many shards as
  ``--workers``/``--shards`` or the sizing rule, :func:`sizing`) in processes of their own; the
  warden a robot process of its own (:mod:`bench.warden`);
- **steady state**, ``--seconds`` long: the broker's and the workers' CPU (from ``/proc``, in %
  of one core), and ``--hazards`` hazards, 2 a second, from the explorer's ``publish`` to the
  warden's receipt, a raw broker hop between two (one queue declared like the ingest's);
- **the views** while the fleet publishes: ``fleetbus team`` and ``fleetbus hazards`` (wall time
  of the command, its start included), and the console's dashboard (``fleetbus api`` in a process
  of its own; the median of 5 renders after the first);
- **the broker's share**: its resident memory at the peak of the steady state and what the fleet's
  virtual host holds (connections, queues, exchanges, bindings), the figures a larger fleet scales;
- **the console's broker poll**: what the dashboard's broker panel asks the management API every
  few seconds (:func:`~fleetbus.api.console.broker_health.ask_broker`), beside the listing of
  every queue of the virtual host with its statistics, which the poll asked for before it asked
  for the service's own queues alone; medians of 5;
- **nothing lost or doubled**: once the fleet stops, the store holds exactly the status events
  the robots had confirmed.

The figures go to ``bench/results/fleet-<UTC time>.json``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from bench.console import ADMIN, PASSWORD, logged_in
from bench.hazard_latency import STAGES, Arrivals, Paced, ping_receiver, publish_paced
from bench.proc import Watch
from bench.processes import worker_process
from bench.raw import declare_queue, ingest_queue_arguments
from bench.report import load_average, machine
from bench.results import percentile, save
from bench.scenario import Context
from bench.telemetry import FLEET_NICE, TelemetryLoad
from bench.warden import WardenProcess
from fleetbus.api.console.broker_health import ask_broker
from fleetbus.broker.management import ManagementAPI
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import blocking_connection
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode
from tests.api.server import api_process
from tests.support import Bus, wait_for

PER_PROCESS = 125
LEAN_PER_PROCESS = 500
PING_QUEUE = "bench.ping"
HAZARD_RATE = 2
console = Console()


def sizing(robots: int, hz: float = 1.0) -> tuple[int, int]:
    """(shards, workers) for ``robots`` each sending ``hz`` events a second, as the scaling guide
    sizes them: a shard per 500 events a second, a worker process per 2 shards, at least one."""
    shards = max(1, math.ceil(robots * hz / 500))
    return shards, max(1, math.ceil(shards / 2))


def fleetbus(bus: Bus, *args: str) -> float:
    """Run ``fleetbus ARGS`` as an operator does; its wall time in seconds."""
    env = {**bus.worker_env(), "COLUMNS": "200"}
    started = time.monotonic()
    command = [sys.executable, "-m", "fleetbus", *args]
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    took = time.monotonic() - started
    if done.returncode != 0:
        raise RuntimeError(f"`fleetbus {' '.join(args)}` failed: {done.stderr[-2000:]}")
    return took


def provision(bus: Bus, robots: list[str], explorer: str, warden: str) -> tuple[float, dict[str, str]]:
    """``fleetbus users add-many`` for ``robots``, an explorer and a warden: (seconds, URLs)."""
    folder = bus.settings.data_dir
    names = folder / "fleet.txt"
    names.write_text("\n".join([f"{explorer} explorer", f"{warden} warden", *robots]) + "\n")
    urls = folder / "fleet-urls.txt"
    bus.accounts += [explorer, warden, *robots]
    took = fleetbus(bus, "users", "add-many", str(names), "--urls", str(urls))
    found = dict(line.split(" ", 1) for line in urls.read_text().splitlines())
    return took, found


@contextlib.contextmanager
def workers(bus: Bus, count: int) -> Iterator[list[int]]:
    with contextlib.ExitStack() as stack:
        pids = [stack.enter_context(worker_process(bus, "--no-recorder")).pid for _ in range(count)]
        yield pids


async def dashboard_ms(base: str, renders: int = 5) -> float:
    client = await logged_in(base, 1)
    try:
        (await client.get("/console/")).raise_for_status()  # the first seeds the team's newest
        times = []
        for _ in range(renders):
            started = time.perf_counter()
            (await client.get("/console/")).raise_for_status()
            times.append(1000 * (time.perf_counter() - started))
        return statistics.median(times)
    finally:
        await client.aclose()


def broker_poll(api: ManagementAPI, vhost: str, times: int = 5) -> dict[str, float]:
    """The console's broker poll, and the whole queue listing it no longer asks for: ms, medians."""

    def median_ms(ask: Callable[[], object]) -> float:
        taken = []
        for _ in range(times):
            started = time.perf_counter()
            ask()
            taken.append(1000 * (time.perf_counter() - started))
        return statistics.median(taken)

    return {
        "console broker poll ms": median_ms(lambda: ask_broker(api, vhost)),
        "every queue listed ms": median_ms(lambda: api.list_queues(vhost)),
    }


def broker_objects(api: ManagementAPI, vhost: str) -> dict[str, float]:
    """What the fleet's virtual host holds on the broker: the per-robot cost a larger fleet scales."""
    return {
        "connections": len(api.list_vhost_connections(vhost)),
        "queues": len(api.list_queues(vhost)),
        "exchanges": len(api.list_exchanges(vhost)),
        "bindings": len(api.list_bindings(vhost)),
    }


def run_size(context: Context, robots: int, args: argparse.Namespace) -> dict[str, float]:
    shards, worker_count = (args.shards, args.workers) if args.shards else sizing(robots)
    figures: dict[str, float] = {"robots": robots, "shards": shards, "workers": worker_count}
    private = context.endpoint.kind == "private"
    broker_pid = LocalNode(load_settings().broker_dir).pid() if private else None
    with context.bus() as bus:
        bus.settings = bus.settings.updated(ingest_shards=shards)
        context.show(f"{robots} robots: provisioning")
        prefix = f"fleet-{bus.vhost[-6:]}"  # accounts are the node's: a run that was killed leaves its own
        names = [f"{prefix}-{i:04d}" for i in range(robots)]
        explorer_name, warden_name = f"{prefix}-explorer", f"{prefix}-warden"
        figures["provisioning s"], urls = provision(bus, names, explorer_name, warden_name)
        declare_queue(bus.admin_url, ingest_queue_arguments(), PING_QUEUE)
        per = args.per_process or (LEAN_PER_PROCESS if args.lean else PER_PROCESS)
        parts = [names[i : i + per] for i in range(0, robots, per)]
        loads = [
            TelemetryLoad(
                bus, [urls[n] for n in part], len(part), ready_timeout=900, lean=args.lean, nice=args.nice
            )
            for part in parts
        ]
        explorer = RobotClient(urls[explorer_name], state_dir=bus.settings.robots_dir)
        bus.clients.append(explorer)
        explorer.connect()
        with (
            workers(bus, worker_count) as worker_pids,
            WardenProcess(bus, urls[warden_name]) as warden,
            contextlib.ExitStack() as running,
        ):
            wait_for(lambda: all(w.localised for w in bus.with_store(lambda r: r.hazards.robots("warden"))))
            context.show(f"{robots} robots connecting")
            connect_started = time.monotonic()
            with ThreadPoolExecutor(len(loads)) as starting:  # the processes connect their robots at once
                for load in starting.map(lambda load: load.__enter__(), loads):
                    running.push(load.__exit__)
            figures["connecting s"] = time.monotonic() - connect_started
            pids = {f"worker{i}": pid for i, pid in enumerate(worker_pids)}
            if broker_pid:
                pids["broker"] = broker_pid
            watch = Watch(pids)
            ping = blocking_connection(bus.admin_url)
            context.show(f"{robots} robots publishing, {args.hazards} hazards")
            done: list[Paced] = []

            def steady() -> None:
                done.append(publish_paced(explorer, ping.channel(), range(args.hazards), HAZARD_RATE))
                time.sleep(max(0.0, args.seconds - args.hazards / HAZARD_RATE))

            with Arrivals(ping_receiver(bus.admin_url), "ping") as pings:
                cpu = watch.measure(steady)
                warden.wait(args.hazards, 120)
                pings.wait(args.hazards, 60)
            ping.close()
            [paced] = done
            if broker_pid:
                figures["broker RSS MB"] = max(watch.rss["broker"], default=float("nan"))
            figures.update(broker_objects(context.api, bus.vhost))
            figures.update(broker_poll(context.api, bus.vhost))
            context.show(f"{robots} robots: the views")
            figures["fleetbus team s"] = fleetbus(bus, "team")
            figures["fleetbus hazards s"] = fleetbus(bus, "hazards")
            with api_process(bus, ADMIN, PASSWORD) as (base, _):
                figures["dashboard ms"] = asyncio.run(dashboard_ms(base))
            running.close()  # the robots stop; each load says how many it had confirmed
            published = sum(load.published for load in loads)
            context.show(f"{robots} robots: the store catching up")
            wait_for(lambda: bus.count("status") >= published, 600, f"{published:,} status events stored")
            figures["status stored / confirmed"] = bus.count("status") / published
        hazard_ms = [1000 * (warden.at[i] - paced.sent[i]) for i in paced.sent]
        ping_ms = [1000 * (pings.at[i] - paced.pinged[i]) for i in paced.pinged]
        figures.update(
            {
                "hazard p50 ms": percentile(hazard_ms, 50),
                "hazard p99 ms": percentile(hazard_ms, 99),
                **{
                    f"hazard {stage} p{q} ms": percentile([1000 * t[k] for t in warden.stages.values()], q)
                    for k, stage in enumerate(STAGES)
                    for q in (50, 99)
                },
                "raw hop p50 ms": percentile(ping_ms, 50),
                "raw hop p99 ms": percentile(ping_ms, 99),
                "broker CPU %": cpu.get("broker", float("nan")),
                "workers CPU %": sum(v for k, v in cpu.items() if k.startswith("worker")),
                "status events/s": sum(load.rate for load in loads),
            }
        )
    return figures


def _shown(value: float) -> str:
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--robots", default="100,300,1000", help="fleet sizes, comma-separated")
    parser.add_argument("--seconds", type=float, default=30.0, help="steady state measured, per size")
    parser.add_argument("--hazards", type=int, default=40)
    parser.add_argument("--shards", type=int, default=0, help="ingest shards (0: the sizing rule)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes, with --shards")
    parser.add_argument("--per-process", type=int, default=0, help="robots a process (125; lean 500)")
    parser.add_argument(
        "--lean",
        action="store_true",
        help="the fleet as bench.lean_robots (one asyncio process speaks for many robots), not RobotClients",
    )
    parser.add_argument(
        "--nice",
        type=int,
        default=FLEET_NICE,
        help=f"the simulated robots' niceness ({FLEET_NICE}: they run on what the server leaves, as robots "
        "elsewhere would; 0: they share the cores equally with the broker and the workers)",
    )
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    started_load = load_average()
    results: dict[str, Any] = {"command": " ".join(sys.argv), "sizes": []}
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        results["machine"] = machine(api, endpoint)
        context = Context(endpoint, api, show=lambda text: console.print(text, highlight=False))
        for size in [int(n) for n in args.robots.split(",")]:
            results["sizes"].append(run_size(context, size, args))
            console.print(results["sizes"][-1], highlight=False)  # each size as soon as measured
    results["load average"] = {"start": started_load, "end": load_average()}
    ended = load_average()
    table = Table(title=f"a fleet on one node; load average {started_load} at the start, {ended} at the end")
    table.add_column("figure")
    for size in results["sizes"]:
        table.add_column(f"{size['robots']:,.0f} robots", justify="right")
    for key in results["sizes"][0]:
        table.add_row(key, *(_shown(size[key]) for size in results["sizes"]))
    console.print(table)
    path = save(Path("bench/results"), "fleet", results)
    console.print(f"wrote {path}", highlight=False)
    Path(path).with_suffix(".txt").write_text(json.dumps(results["sizes"], indent=1))


if __name__ == "__main__":
    main()
