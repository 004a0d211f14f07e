"""Ingest with 1, 2 and 4 worker processes on one machine, beside the raw broker rate of the same run.

    .venv/bin/python -m bench.scaling [--events 80000] [--robots 8] [--shards 4] [--workers 1 2 4] [--runs 3]

Each run, in a fresh virtual host and data folder:

  raw publish      pika, persistent messages as large as the events, pipelined confirms, into a
                   quorum queue declared like an ingest shard
  raw consume      aio-pika, one process, manual acks, prefetch 512, from that queue
  raw consume xP   the same with P processes at once (P = the most workers), each on a queue of
                   its own: what the broker and the Python client can do in parallel on this machine
  drain, W workers --robots robots (spread evenly over --shards shards) have queued --events
                   status events; W ``fleetbus worker`` processes start (the bench holds the shards'
                   leases until all are up, then lets go, so they begin together). Measured from
                   the moment each worker holds its share until 85 % of the events are stored
                   (the shards drain evenly, so every worker is busy all along); the workers' and
                   the broker's CPU in that window
  ingest, W workers W workers run; the robots (threads of this process) publish the events with
                   pipelined confirms; from the first publish until the store holds them all
  takeover         two workers share the shards; one is stopped (SIGTERM), or killed (SIGKILL):
                   seconds until the other holds every shard

Every scenario checks that the store ends with exactly --events events (none lost, none doubled),
each robot's stored in the order it published them.

From the benchmark suite: ``bench.scaling.run(events=..., runs=...)`` returns the same results as
a dict (``runs``, ``medians``, ``spreads``, the options); ``main()`` prints them and writes
``bench/results/scaling-<time>.json``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.ingest import event_size, status_items
from bench.proc import cpu_seconds
from bench.raw import raw_consume, raw_publish
from bench.results import medians, save, spread
from fleetbus.broker.accounts import Account, Role, fresh_vhost, provision_account
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.topology import INGEST_QUEUE_ARGUMENTS, QueueSpec, Topology, declare_with_url
from fleetbus.broker.urls import without_password
from fleetbus.publishers.client import RobotClient
from fleetbus.settings import Settings, load_settings
from fleetbus.workers.setup import set_up_service
from fleetbus.workers.shards import SHARD_PREFIX, WORKER_PREFIX, shard_lease, share
from fleetbus.workers.store import Repositories, repositories_for
from fleetbus.workers.store.base import EventQuery, EventRecord
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode

VHOST = "fleetbus-bench-scaling"
POLL_SECONDS = 0.05
#: The bench's name as the holder of the shards while the workers start.
GATE = "bench-gate:0:scaling"
#: The drain is timed until this share of the events is stored: before any shard runs dry.
WINDOW_END = 0.85
console = Console()


@dataclass(frozen=True)
class Options:
    events: int = 40_000
    robots: int = 8
    shards: int = 4
    workers: tuple[int, ...] = (1, 2, 4)
    mongodb_url: str | None = None
    """Run the workers on this MongoDB server (a database of the run's own) instead of SQLite."""
    cluster: bool = False
    """The broker is a cluster (``FLEETBUS_CLUSTER``): quorum queues, and no one broker PID to watch."""


# raw broker


def raw_queue(n: int) -> str:
    return f"bench.raw.{n}"


def _consume_process(url: str, queue: str, count: int, ready: Any, results: Any) -> None:
    ready.wait()  # every process started and imported: they begin together
    results.put(asyncio.run(raw_consume(url, count, queue)))


def parallel_consume(url: str, count: int, processes: int) -> float:
    """``processes`` consumers at once, each on its own queue of count / processes messages; the
    rate of all together (they begin at once, so the slowest one's time is the whole's)."""
    context = multiprocessing.get_context("spawn")
    ready, results = context.Barrier(processes), context.Queue()
    each = count // processes
    workers = [
        context.Process(target=_consume_process, args=(url, raw_queue(n), each, ready, results))
        for n in range(processes)
    ]
    for worker in workers:
        worker.start()
    rates = [results.get(timeout=600) for _ in workers]
    for worker in workers:
        worker.join(60)
    return each * processes / max(each / rate for rate in rates)


def raw_rates(admin_url: str, events: int, processes: int) -> dict[str, float]:
    queues = tuple(QueueSpec(raw_queue(n), INGEST_QUEUE_ARGUMENTS) for n in range(max(processes, 1)))
    asyncio.run(declare_with_url(admin_url, [Topology(queues=queues)]))
    size = event_size()
    result = {"raw_publish": raw_publish(admin_url, events, size, raw_queue(0))}
    result["raw_consume"] = asyncio.run(raw_consume(admin_url, events, raw_queue(0)))
    if processes > 1:
        for n in range(processes):
            raw_publish(admin_url, events // processes, size, raw_queue(n))
        result[f"raw_consume_x{processes}"] = parallel_consume(admin_url, events, processes)
    return result


# fleetbus


class Probe:
    """What the bench watches while workers run: the store's count and its shard leases."""

    def __init__(self, settings: Settings) -> None:
        self._loop = asyncio.new_event_loop()
        self._repositories: Repositories = repositories_for(settings)
        self._loop.run_until_complete(self._repositories.open())

    def stored(self) -> int:
        return self._loop.run_until_complete(self._repositories.events.count_events())

    def verify(self, total: int, what: str) -> None:
        """Exactly ``total`` events stored (the store's (robot, epoch, seq) key refuses doubles), and
        each robot's stored in the order it published them (its numbering in its client's epoch)."""
        stored = self.stored()
        if stored != total:
            raise AssertionError(f"{what} stored {stored} events, not {total}")
        records = self._loop.run_until_complete(self._repositories.events.find_events(EventQuery()))
        by_numbering: dict[tuple[str, str], list[EventRecord]] = {}
        for record in records:
            by_numbering.setdefault((record.robot_id, record.epoch), []).append(record)
        for (robot, epoch), mine in sorted(by_numbering.items()):
            arrival = [record.received_at for record in sorted(mine, key=lambda record: record.seq)]
            if arrival != sorted(arrival):
                raise AssertionError(
                    f"{what}: a later event of {robot} (epoch {epoch}) was stored before an earlier one"
                )

    def holders(self, prefix: str = SHARD_PREFIX) -> Counter[str]:
        now = datetime.now(timezone.utc)
        leases = self._loop.run_until_complete(self._repositories.leases.leases(prefix))
        return Counter(lease.holder for lease in leases if lease.live(now))

    def close_gate(self, shards: int) -> None:
        """Hold every shard's lease as the bench, so starting workers wait for one another."""
        now = datetime.now(timezone.utc)
        for shard in range(shards):
            done = self._repositories.leases.acquire_lease(
                shard_lease(shard), GATE, now + timedelta(minutes=5), now
            )
            assert self._loop.run_until_complete(done)

    def open_gate(self, shards: int) -> None:
        """Let every shard go at once: the waiting workers each take their share at their next beat."""
        for shard in range(shards):
            self._loop.run_until_complete(self._repositories.leases.release_lease(shard_lease(shard), GATE))

    def close(self) -> None:
        self._loop.run_until_complete(self._repositories.close())
        self._loop.close()


@dataclass
class Fleet:
    settings: Settings
    accounts: list[Account]
    broker_pid: int | None
    service_url: str
    """The workers' account (``fleetbus setup`` made it; its password is kept in the data folder)."""

    def env(self) -> dict[str, str]:
        """A worker's environment: the service account alone, no administrator."""
        env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
        env.update(
            FLEETBUS_SERVICE_URL=without_password(self.service_url),
            FLEETBUS_DATA_DIR=str(self.settings.data_dir),
            FLEETBUS_INGEST_SHARDS=str(self.settings.ingest_shards),
            FLEETBUS_CLUSTER="true" if self.settings.cluster else "false",
        )
        if self.settings.mongodb_url:
            env["FLEETBUS_MONGODB_URL"] = self.settings.mongodb_url
        return env

    def publish_all(self, events: int) -> float:
        """Every robot publishes its share of ``events`` at once (threads); returns when confirmed."""
        each = events // len(self.accounts)
        started = time.perf_counter()

        def publish(account: Account) -> None:
            with RobotClient(account.amqp_url, state_dir=self.settings.robots_dir) as robot:
                for start in range(0, each, 5000):
                    robot.publish_many(status_items(min(5000, each - start)))

        threads = [threading.Thread(target=publish, args=(account,)) for account in self.accounts]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        return started


@contextmanager
def fleet(endpoint: BrokerEndpoint, api: ManagementAPI, options: Options) -> Iterator[Fleet]:
    """A fresh virtual host and data folder with ``options.robots`` robots spread over the shards."""
    admin_url = fresh_vhost(api, endpoint.amqp_url, VHOST)
    with tempfile.TemporaryDirectory() as tmp:
        database = f"bench_scaling_{int(time.time())}"
        settings = load_settings().updated(
            data_dir=Path(tmp),
            amqp_url=admin_url,
            management_url=endpoint.management_url,
            mongodb_url=f"{options.mongodb_url.rstrip('/')}/{database}" if options.mongodb_url else None,
            ingest_shards=options.shards,
            cluster=options.cluster,
        )
        accounts = [
            asyncio.run(
                provision_account(
                    admin_url,
                    api,
                    f"bench-robot{n}",
                    Role.ROBOT,
                    rotate=True,
                    shards=options.shards,
                    cluster=options.cluster,
                )
            )
            for n in range(options.robots)
        ]
        single = endpoint.kind == "private" and not options.cluster
        broker_pid = LocalNode(load_settings().broker_dir).pid() if single else None
        service = asyncio.run(set_up_service(settings, replace(endpoint, amqp_url=admin_url)))
        try:
            yield Fleet(settings, accounts, broker_pid, service.service_url)
        finally:
            for account in accounts:
                api.delete_user(account.name)
            api.delete_vhost(VHOST)


@dataclass
class Workers:
    processes: list[subprocess.Popen[bytes]]
    log: Path

    @property
    def pids(self) -> list[int]:
        return [process.pid for process in self.processes]

    def check(self) -> None:
        """Raise, with the end of their log, when a worker has ended."""
        ended = [process.returncode for process in self.processes if process.poll() is not None]
        if ended:
            tail = "\n".join(self.log.read_text(errors="replace").splitlines()[-30:])
            raise RuntimeError(f"a worker ended (exit {ended}); its log ends:\n{tail}")


@contextmanager
def worker_processes(fleet_: Fleet, count: int) -> Iterator[Workers]:
    path = fleet_.settings.data_dir / f"workers-{count}.log"
    command = [sys.executable, "-m", "fleetbus", "worker", "--no-recorder"]
    with open(path, "ab") as log:
        workers = Workers(
            [
                subprocess.Popen(command, env=fleet_.env(), stdout=log, stderr=subprocess.STDOUT)
                for _ in range(count)
            ],
            path,
        )
        try:
            yield workers
        finally:
            for worker in workers.processes:
                worker.terminate()
            for worker in workers.processes:
                worker.wait(60)


def wait_until(condition: Callable[[], bool], timeout: float, what: str, workers: Workers) -> float:
    deadline = time.monotonic() + timeout
    while not condition():
        workers.check()
        if time.monotonic() > deadline:
            tail = "\n".join(workers.log.read_text(errors="replace").splitlines()[-30:])
            raise TimeoutError(f"no {what} within {timeout:.0f} s; the workers' log ends:\n{tail}")
        time.sleep(POLL_SECONDS)
    return time.monotonic()


def balanced(probe: Probe, shards: int, workers: int) -> bool:
    expected = sorted(share(shards, [str(n) for n in range(workers)], str(n)) for n in range(workers))
    return sorted(probe.holders().values()) == [n for n in expected if n]


def drain(endpoint: BrokerEndpoint, api: ManagementAPI, options: Options, workers: int) -> dict[str, float]:
    with fleet(endpoint, api, options) as team:
        team.publish_all(options.events)
        total = options.events // options.robots * options.robots
        probe = Probe(team.settings)
        try:
            # started together, else the first worker up would drain most of the backlog alone
            probe.close_gate(options.shards)
            with worker_processes(team, workers) as group:
                pids = group.pids
                wait_until(
                    lambda: len(probe.holders(WORKER_PREFIX)) == workers, 120, "every worker up", group
                )
                probe.open_gate(options.shards)
                wait_until(
                    lambda: balanced(probe, options.shards, workers), 120, "share for every worker", group
                )
                started, first = time.monotonic(), probe.stored()
                cpu = {pid: cpu_seconds(pid) for pid in pids}
                broker = cpu_seconds(team.broker_pid) if team.broker_pid else 0.0
                if first >= total * WINDOW_END / 2:
                    raise RuntimeError(
                        f"{first} of {total} stored before the shares were even: use more --events"
                    )
                ended = wait_until(lambda: probe.stored() >= total * WINDOW_END, 600, "most stored", group)
                last = probe.stored()
                window = ended - started
                worker_cpu = sum(cpu_seconds(pid) - cpu[pid] for pid in pids)
                broker_cpu = cpu_seconds(team.broker_pid) - broker if team.broker_pid else float("nan")
                wait_until(lambda: probe.stored() >= total, 600, "every event stored", group)
            probe.verify(total, f"drain with {workers} workers")
        finally:
            probe.close()
    return {
        f"drain_{workers}w": (last - first) / window,
        f"drain_{workers}w_worker_cpu": 100 * worker_cpu / window,
        f"drain_{workers}w_broker_cpu": 100 * broker_cpu / window,
    }


def ingest(endpoint: BrokerEndpoint, api: ManagementAPI, options: Options, workers: int) -> dict[str, float]:
    with fleet(endpoint, api, options) as team:
        total = options.events // options.robots * options.robots
        probe = Probe(team.settings)
        try:
            with worker_processes(team, workers) as group:
                wait_until(
                    lambda: balanced(probe, options.shards, workers), 120, "share for every worker", group
                )
                started = team.publish_all(options.events)
                wait_until(lambda: probe.stored() >= total, 600, "every event stored", group)
                elapsed = time.perf_counter() - started
            probe.verify(total, f"ingest with {workers} workers")
        finally:
            probe.close()
    return {f"ingest_{workers}w": total / elapsed}


def takeover(endpoint: BrokerEndpoint, api: ManagementAPI, options: Options) -> dict[str, float]:
    """Two workers share the shards; one stops (SIGTERM), or is killed (SIGKILL): seconds until the
    other consumes every shard."""
    result = {}
    with fleet(endpoint, api, options) as team:
        probe = Probe(team.settings)
        try:
            for how, end in (("sigterm", subprocess.Popen.terminate), ("sigkill", subprocess.Popen.kill)):
                with worker_processes(team, 2) as group:
                    wait_until(
                        lambda: balanced(probe, options.shards, 2), 120, "share for both workers", group
                    )
                    gone, survivor = group.processes
                    started = time.monotonic()
                    end(gone)
                    gone.wait(60)
                    alone = Workers([survivor], group.log)
                    done = wait_until(
                        lambda: balanced(probe, options.shards, 1), 60, "every shard taken over", alone
                    )
                    result[f"takeover_{how}_s"] = done - started
        finally:
            probe.close()
    return result


def one_run(
    endpoint: BrokerEndpoint, api: ManagementAPI, options: Options, step: Callable[[str], None]
) -> dict[str, float]:
    admin_url = fresh_vhost(api, endpoint.amqp_url, VHOST)
    step("raw broker")
    result = raw_rates(admin_url, options.events, max(options.workers))
    api.delete_vhost(VHOST)
    for workers in options.workers:
        step(f"drain, {workers} workers")
        result.update(drain(endpoint, api, options, workers))
    for workers in options.workers:
        step(f"ingest, {workers} workers")
        result.update(ingest(endpoint, api, options, workers))
    step("takeover")
    result.update(takeover(endpoint, api, options))
    result["load_average"] = os.getloadavg()[1]  # the machine's load over the last 5 minutes
    return result


def run(
    events: int = 80_000,
    robots: int = 8,
    shards: int = 4,
    workers: Sequence[int] = (1, 2, 4),
    runs: int = 3,
    mongodb_url: str | None = None,
    step: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The scaling scenario ``runs`` times; the results as one JSON-ready dict."""
    options = Options(events, robots, shards, tuple(workers), mongodb_url)
    endpoint = resolve_broker(load_settings(), start=True)
    results: list[dict[str, float]] = []
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        for n in range(runs):

            def tell(what: str, n: int = n) -> None:
                if step is not None:
                    step(f"run {n + 1}/{runs}: {what}")

            results.append(one_run(endpoint, api, options, tell))
    keys = list(results[0])
    return {
        "events": events,
        "robots": robots,
        "shards": shards,
        "workers": list(workers),
        "store": "mongodb" if mongodb_url else "sqlite",
        "event_bytes": event_size(),
        "cores": os.cpu_count(),
        "runs": results,
        "medians": medians(results),
        "spreads": {key: spread(results, key, digits=1 if key.endswith("_s") else 0) for key in keys},
    }


def table(result: dict[str, Any]) -> Table:
    middle = result["medians"]
    raw = middle["raw_consume"]
    out = Table(
        title=f"msg/s, median of {len(result['runs'])} runs of {result['events']:,} events "
        f"({result['event_bytes']} B) from {result['robots']} robots over {result['shards']} shards, "
        f"{result['store']}, {result['cores']} cores"
    )
    for column in ("scenario", "median msg/s", "spread", "vs raw consume", "vs 1 worker", "CPU % of a core"):
        out.add_column(column, justify="left" if column == "scenario" else "right")
    for key in ("raw_publish", "raw_consume", *(k for k in middle if k.startswith("raw_consume_x"))):
        ratio = f"{middle[key] / raw:.2f}"
        out.add_row(key.replace("_", " "), f"{middle[key]:,.0f}", result["spreads"][key], ratio, "", "")
    for kind in ("drain", "ingest"):
        one = middle.get(f"{kind}_1w")
        for workers in result["workers"]:
            key = f"{kind}_{workers}w"
            cpu = ""
            if kind == "drain":
                cpu = f"workers {middle[key + '_worker_cpu']:.0f}, broker {middle[key + '_broker_cpu']:.0f}"
            out.add_row(
                f"{kind}, {workers} worker{'s' if workers > 1 else ''}",
                f"{middle[key]:,.0f}",
                result["spreads"][key],
                f"{middle[key] / raw:.2f}",
                f"{middle[key] / one:.2f}" if one else "",
                cpu,
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--events", type=int, default=80_000)
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--shards", type=int, default=4)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--mongodb", action="store_true", help="workers on FLEETBUS_MONGODB_URL, not SQLite")
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    mongodb_url = load_settings().mongodb_url if args.mongodb else None
    if args.mongodb and not mongodb_url:
        parser.error("--mongodb needs FLEETBUS_MONGODB_URL")
    steps = args.runs * (2 + 2 * len(args.workers))
    with Progress(console=console) as progress:
        task = progress.add_task("scaling", total=steps)
        begun = 0

        def step(what: str) -> None:
            nonlocal begun
            progress.update(task, description=what, completed=begun)  # the phases before it are done
            begun += 1

        result = run(args.events, args.robots, args.shards, args.workers, args.runs, mongodb_url, step)
        progress.update(task, completed=steps)
    console.print(table(result))
    loads = [round(run["load_average"], 1) for run in result["runs"]]
    console.print(f"the machine's load average (5 min) at the end of each run: {loads}")
    for how, signal_name in (("sigterm", "stopped (SIGTERM)"), ("sigkill", "killed (SIGKILL)")):
        key = f"takeover_{how}_s"
        console.print(
            f"a worker {signal_name}: the other holds every shard after {result['medians'][key]:.1f} s "
            f"(spread {result['spreads'][key]} s)"
        )
    console.print(f"wrote {save(args.out, 'scaling', result)}")


if __name__ == "__main__":
    main()
