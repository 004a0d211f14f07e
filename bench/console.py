"""The operator console under a team's traffic: how soon open dashboards show an event, the
console's memory over many reconnections, and how fast its pages render on a large store.

    .venv/bin/python -m bench.console [--robots 100] [--dashboards 20] [--maps 20] [--seconds 60]
        [--reconnects 1000] [--hazards 10000] [--messages 1000000] [--renders 50] [--browser-renders 10]

Each part runs on a virtual host, data folder and SQLite store of its own, with every process as
deployed: `fleetbus worker` and `fleetbus api` (which serves the console) each in a process of its
own, the robots in another (``bench.telemetry``: each robot publishes a status and a localisation
a second, confirmed, through the broker), and this process the operators: dashboards as httpx
streams of the dashboard's server-sent events (not browsers), logged in as an administrator
through the console's own form.

  live        for --seconds, --dashboards open dashboards note when each event's row arrives, while
              --maps live maps are open too (their streams read and counted). The latency runs from
              the event's ``received_at`` (the worker's stamp, read back from the store) to its row's
              arrival at a dashboard: median and p95 over every (dashboard, event) pair (targets:
              p95 under 200 ms with 100 robots, under 300 ms with 300), rows that never arrived, and
              the console process's CPU time meanwhile. Split in two at the moment this process
              first saw the event committed in the store (it reads the SQLite file every 20 ms, by
              itself): the worker's part (stamp to commit) and the console's (commit to row). The
              robots' process runs at --nice (15: on what the server leaves, as robots on machines
              of their own). Meanwhile a robot of this process reports a hazard a second, and each
              map notes when a mark of each hazard first arrives (provisional or registered): hazard
              to map, from the hazard's ``received_at``, median and p95 over every (map, hazard).
  reconnects  the robots and dashboards going on, one more dashboard's stream opened --reconnects
              times, each sending the Last-Event-ID of the one before (so each is replayed what it
              missed from the store) and dropped after its first event; the console process's
              resident memory (VmRSS) after each: first, last, highest.
  renders     a store of its own seeded through the repositories (progress shown): --messages events
              of the robots in the event log (--hazards of them hazards, registered in every state:
              held, announced, claimed, reached, cleared), the same number of messages in the
              recorder's recording; then each console page an administrator may open (``sitemap.PAGES``)
              fetched --renders times, and the live map's trails of each window it offers: median
              and p95; then the dashboard and the live map drawn
              --browser-renders times in headless chromium (``bench.console_browser``): median and
              p95, against the target (under 1 s with 1,000 robots in the team).

Results go to ``bench/results/console-<UTC time>.json`` with the command and the load average.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import sqlite3
import statistics
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
from httpx_sse import aconnect_sse
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from bench.console_browser import browser_times
from bench.ingest import status_body
from bench.proc import cpu_seconds, rss_megabytes
from bench.processes import worker_process
from bench.replay import write_recording
from bench.report import load_average
from bench.results import percentile, save
from bench.scenario import Context, Figures
from bench.telemetry import FLEET_NICE, POSE, TelemetryLoad
from fleetbus.api.console.live import FRAGMENT_EVENT
from fleetbus.api.console.pages.live_map import event_mark
from fleetbus.api.console.session import CSRF_COOKIE, CSRF_FIELD
from fleetbus.api.console.sitemap import PAGES
from fleetbus.api.console.trails import WINDOWS
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.envelope import new_epoch
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.hazards import Hazard, NewHazard
from fleetbus.workers.store.repositories import Repositories
from tests.api.server import api_process
from tests.factories import hazard

ADMIN = "bench-console-admin"
PASSWORD = "bench console password"
STREAM = "/console/stream/dashboard"
MAP_STREAM = "/console/stream/map"
ROW = re.compile(r'\s*<tr id="(event-[^"]+)"')
#: A hazard's mark on the live map: the provisional one sent at once from its event
#: (``map/news.html``), or the registered one (``map/marks.html``); either names the event.
HAZARD_MARK = re.compile(r'<li id="mark-(?:new|hazard)-[^"]+" [^>]*data-event="([^"]+)"')
#: A hazard a second goes through the whole chain while the dashboards and maps are open.
HAZARD_EVERY_S = 1.0
WARDEN_EVERY = 10
"""One robot in ten is a warden (the hazards' claims and clearances are theirs)."""
WRITE_BATCH = 10_000
#: The dashboard and the live map drawn in a browser within this, with 1,000 robots in the team.
DRAWN_TARGET_MS = 1_000
console = Console()


def robot_name(i: int) -> str:
    return f"bench-console{i}"


def row_id(record: EventRecord) -> str:
    """The id of the event's row on the dashboard (``dashboard/event.html``)."""
    return row_id_of(record.robot_id, record.epoch, record.seq)


def row_id_of(robot_id: str, epoch: str, seq: int) -> str:
    return f"event-{robot_id}-{epoch}-{seq}"


async def logged_in(base: str, connections: int) -> httpx.AsyncClient:
    """An httpx client with the administrator's console session (through the login form, CSRF
    value included), for ``connections`` streams at once."""
    limits = httpx.Limits(max_connections=connections, max_keepalive_connections=connections)
    client = httpx.AsyncClient(base_url=base, timeout=httpx.Timeout(60, read=None), limits=limits)
    await client.get("/console/login")
    form = {"username": ADMIN, "password": PASSWORD, CSRF_FIELD: client.cookies[CSRF_COOKIE]}
    reply = await client.post("/console/login", data=form)
    assert reply.status_code == 303, f"logging in to the console: {reply.status_code} {reply.text[:200]}"
    return client


@dataclass
class Dashboard:
    """One open dashboard: when each event's row first arrived (``time.time()``)."""

    arrivals: dict[str, float] = field(default_factory=dict)
    cuts: int = 0
    """Times its stream ended under it (the console cut it for falling behind); it reconnects."""
    fragments: int = 0
    """Fragments received (rows, markers, counts)."""
    opened: asyncio.Event = field(default_factory=asyncio.Event)


async def follow(client: httpx.AsyncClient, dashboard: Dashboard, stream: str = STREAM) -> None:
    """Read a page's stream (the dashboard's, or ``stream``) until cancelled; reconnect, as live.js
    does, if it ends."""
    last_id: str | None = None
    while True:
        headers = {"Last-Event-ID": last_id} if last_id else {}
        try:
            async with aconnect_sse(client, "GET", stream, headers=headers) as source:
                source.response.raise_for_status()
                async for event in source.aiter_sse():
                    now = time.time()
                    if event.event != FRAGMENT_EVENT:
                        continue
                    last_id = event.id or last_id
                    dashboard.opened.set()
                    fragments = json.loads(event.data)
                    dashboard.fragments += len(fragments)
                    for fragment in fragments:
                        if found := ROW.match(fragment):
                            dashboard.arrivals.setdefault(found.group(1), now)
                        for mark in HAZARD_MARK.finditer(fragment):
                            dashboard.arrivals.setdefault(f"hazard {mark.group(1)}", now)
        except httpx.HTTPError:
            pass  # counted below, as a stream that ended
        dashboard.cuts += 1


async def reconnections(
    client: httpx.AsyncClient, pid: int, count: int, show: Callable[[str], None]
) -> list[float]:
    """Open the dashboard's stream ``count`` times, each with the last event id of the one before,
    until its first event; the console process's resident memory (MB) after each."""
    resident: list[float] = []
    last_id: str | None = None
    for i in range(count):
        headers = {"Last-Event-ID": last_id} if last_id else {}
        async with aconnect_sse(client, "GET", STREAM, headers=headers) as source:
            source.response.raise_for_status()
            async for event in source.aiter_sse():
                if event.event == FRAGMENT_EVENT:
                    last_id = event.id
                    break
        resident.append(rss_megabytes(pid))
        if i % 10 == 0:
            show(f"reconnection {i + 1:,} of {count:,}: console {resident[-1]:.1f} MB resident")
    return resident


#: How often the bench looks in the store for the events the worker committed (the split's edge).
VISIBLE_EVERY_S = 0.02
#: How far back each look reaches: the worker commits a batch after stamping its first event.
VISIBLE_BACK_US = 2_000_000


@dataclass
class Visibility:
    """When each event was first seen committed in the store (``time.time()``): what splits an
    event's way to the page into the worker's part and the console's."""

    seen: dict[str, float] = field(default_factory=dict)


def look_in_store(path: Path, visibility: Visibility, stop: threading.Event) -> None:
    """Every :data:`VISIBLE_EVERY_S`, the keys of the events received lately, read straight from
    the SQLite file (read-only, no decoding: the bench must not take what it measures from the
    console)."""
    connection = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    newest = time.time_ns() // 1000
    try:
        while not stop.wait(VISIBLE_EVERY_S):
            rows = connection.execute(
                "SELECT robot_id, epoch, seq, received_at FROM events WHERE received_at >= ?",
                (newest - VISIBLE_BACK_US,),
            ).fetchall()
            now = time.time()
            for robot_id, epoch, seq, received_at in rows:
                visibility.seen.setdefault(row_id_of(robot_id, epoch, seq), now)
                newest = max(newest, received_at)
    finally:
        connection.close()


@dataclass
class Watched:
    dashboards: list[Dashboard]
    maps: list[Dashboard]
    """The open live maps (their streams' fragments and cuts: the load they add)."""
    start: float
    end: float
    console_cpu: float
    """The console process's CPU time over the live part, in % of one core."""
    resident: list[float]
    visibility: Visibility


def publish_hazards(robot: RobotClient, stop: threading.Event) -> None:
    """A hazard every :data:`HAZARD_EVERY_S` through the robot client (confirmed), until ``stop``."""
    number = 0
    while not stop.wait(HAZARD_EVERY_S):
        robot.publish(EventType.HAZARD, hazard(number, description=f"bench hazard {number}"))
        number += 1


async def watch(
    base: str,
    pid: int,
    store: Path,
    args: argparse.Namespace,
    show: Callable[[str], None],
    robot: RobotClient,
) -> Watched:
    """The dashboards open for ``args.seconds`` while ``robot`` reports a hazard a second, then the
    reconnections (the dashboards still open)."""
    client = await logged_in(base, args.dashboards + args.maps + 2)
    dashboards = [Dashboard() for _ in range(args.dashboards)]
    maps = [Dashboard() for _ in range(args.maps)]
    visibility, stop_looking = Visibility(), threading.Event()
    looking = threading.Thread(target=look_in_store, args=(store, visibility, stop_looking), daemon=True)
    looking.start()
    followers = [asyncio.create_task(follow(client, dashboard)) for dashboard in dashboards]
    followers += [asyncio.create_task(follow(client, page, MAP_STREAM)) for page in maps]
    try:
        async with asyncio.timeout(120):
            for dashboard in dashboards + maps:
                await dashboard.opened.wait()
        await asyncio.sleep(2)  # past the first batches after opening: the measurement's start
        start, cpu = time.time(), cpu_seconds(pid)
        show(f"{args.dashboards} dashboards and {args.maps} maps open for {args.seconds:g} s")
        stop_hazards = threading.Event()
        hazards = threading.Thread(target=publish_hazards, args=(robot, stop_hazards), daemon=True)
        hazards.start()
        await asyncio.sleep(args.seconds)
        end = time.time()
        stop_hazards.set()
        await asyncio.to_thread(hazards.join)
        console_cpu = 100 * (cpu_seconds(pid) - cpu) / (end - start)
        await asyncio.sleep(3)  # the rows of the last events measured are on their way
        resident = await reconnections(client, pid, args.reconnects, show)
    finally:
        stop_looking.set()
        for follower in followers:
            follower.cancel()
        await asyncio.gather(*followers, return_exceptions=True)
        await client.aclose()
    return Watched(dashboards, maps, start, end, console_cpu, resident, visibility)


async def received_between(repos: Repositories, start: float, end: float) -> list[EventRecord]:
    """The events received from ``start`` to ``end`` (``time.time()``), read a page at a time."""
    found: dict[tuple[str, str, int], EventRecord] = {}
    since, until = datetime.fromtimestamp(start, timezone.utc), datetime.fromtimestamp(end, timezone.utc)
    while True:
        page = await repos.events.events_received_since(since, WRITE_BATCH)
        found.update((record.key, record) for record in page if record.received_at <= until)
        if len(page) < WRITE_BATCH or page[-1].received_at >= until or page[-1].received_at == since:
            return list(found.values())
        since = page[-1].received_at


def console_settings(args: argparse.Namespace) -> dict[str, str]:
    """The settings `fleetbus api` is given beyond the bus's own."""
    return {} if args.poll_s is None else {"FLEETBUS_CONSOLE_POLL_S": str(args.poll_s)}


def live(context: Context, args: argparse.Namespace) -> dict[str, Any]:
    """The live and reconnects parts, on one team."""
    with context.bus() as bus:
        context.show(f"{args.robots} robot accounts")
        urls = [bus.add(robot_name(i), kind=RobotKind.EXPLORER).amqp_url for i in range(args.robots)]
        reporter = bus.robot(bus.add("bench-console-hazards", kind=RobotKind.EXPLORER))
        with (
            worker_process(bus, "--no-recorder"),
            api_process(bus, ADMIN, PASSWORD, **console_settings(args)) as (base, api),
            TelemetryLoad(bus, urls, 2 * args.robots, pose=True, nice=args.nice) as load,
        ):
            context.show(f"{args.robots} robots publishing")
            watched = asyncio.run(
                watch(base, api.pid, bus.settings.sqlite_path, args, context.show, reporter)
            )
        measured = bus.with_store(lambda repos: received_between(repos, watched.start, watched.end))
        hazards = bus.with_store(lambda repos: repos.hazards.recent_hazards(MOST_HAZARDS_MEASURED))
        figures = {**live_figures(load.rate, measured, watched), **map_figures(hazards, watched)}
        console.print(part_table("live and reconnects", figures))  # before the team is taken down
    return {"figures": figures, "console RSS MB every 10th reconnection": watched.resident[::10]}


def live_figures(rate: float, measured: list[EventRecord], watched: Watched) -> Figures:
    latencies: list[float] = []
    to_store: list[float] = []
    store_to_page: list[float] = []
    missing = 0
    for record in measured:
        row = row_id(record)
        visible = watched.visibility.seen.get(row)
        if visible is not None:
            to_store.append((visible - record.received_at.timestamp()) * 1000)
        for dashboard in watched.dashboards:
            arrived = dashboard.arrivals.get(row)
            if arrived is None:
                missing += 1
            else:
                latencies.append((arrived - record.received_at.timestamp()) * 1000)
                if visible is not None:
                    store_to_page.append((arrived - visible) * 1000)
    resident = watched.resident
    return {
        "robots' events/s": rate,
        "events measured": len(measured),
        "event to dashboard median ms": statistics.median(latencies),
        "event to dashboard p95 ms": percentile(latencies, 95),
        "event to dashboard p99 ms": percentile(latencies, 99),
        "event to dashboard max ms": max(latencies),
        "of which worker to store median ms": statistics.median(to_store),
        "of which worker to store p95 ms": percentile(to_store, 95),
        "of which store to dashboard median ms": statistics.median(store_to_page),
        "of which store to dashboard p95 ms": percentile(store_to_page, 95),
        "rows never shown": missing,
        "dashboard streams cut": sum(d.cuts for d in watched.dashboards),
        "maps open": len(watched.maps),
        "map fragments received": sum(m.fragments for m in watched.maps),
        "map streams cut": sum(m.cuts for m in watched.maps),
        "console CPU % of a core": watched.console_cpu,
        "console RSS MB, first reconnection": resident[0],
        "console RSS MB, last reconnection": resident[-1],
        "console RSS MB, highest": max(resident),
        "console RSS last ÷ first": resident[-1] / resident[0],
    }


#: The live part's hazards read back from the store: more than it can publish in its seconds.
MOST_HAZARDS_MEASURED = 100_000


def map_figures(hazards: list[Hazard], watched: Watched) -> Figures:
    """How soon each hazard's mark reached every open map: from the hazard's ``received_at`` (the
    worker's stamp) to the first arrival of a mark of it (provisional or registered) in a map's
    stream."""
    latencies: list[float] = []
    missing = 0
    for found in hazards:
        for page in watched.maps:
            arrived = page.arrivals.get(f"hazard {event_mark(found.robot_id, found.epoch, found.seq)}")
            if arrived is None:
                missing += 1
            else:
                latencies.append((arrived - found.received_at.timestamp()) * 1000)
    if not latencies:
        return {"hazards published": len(hazards), "hazard markers never shown": missing}
    return {
        "hazards published": len(hazards),
        "hazard to map median ms": statistics.median(latencies),
        "hazard to map p95 ms": percentile(latencies, 95),
        "hazard to map max ms": max(latencies),
        "hazard markers never shown": missing,
    }


def seeded_events(robots: int, count: int, hazards: int, until: datetime) -> Iterator[list[EventRecord]]:
    """``count`` events of ``robots`` robots, received 5 ms apart up to ``until``, in batches:
    statuses and localisations in turn, with ``hazards`` hazards spread evenly among them."""
    epochs = [new_epoch(until) for _ in range(robots)]
    hazard_every = count // hazards if hazards else 0
    start = until - timedelta(milliseconds=5 * count)
    batch: list[EventRecord] = []
    for i in range(count):
        robot, seq = robot_name(i % robots), i // robots
        at = start + timedelta(milliseconds=5 * i)
        if hazard_every and i % hazard_every == 0 and i // hazard_every < hazards:
            kind, body = (
                EventType.HAZARD.value,
                hazard(i, description=f"Smoke in corridor {i // hazard_every}"),
            )
        elif i % 2:
            kind, body = POSE[0].value, POSE[1]
        else:
            kind, body = EventType.STATUS.value, status_body()
        batch.append(
            EventRecord(
                robot_id=robot,
                epoch=epochs[i % robots],
                seq=seq,
                type=kind,
                message_id=f"00000000-0000-4000-9000-{i:012d}",
                sent_at=at - timedelta(milliseconds=5),
                received_at=at,
                body=body,
                user_id=robot,
                exchange=f"{robot}.events",
                routing_key=f"{robot}.{kind}",
            )
        )
        if len(batch) == WRITE_BATCH:
            yield batch
            batch = []
    if batch:
        yield batch


async def seed(
    repos: Repositories, robots: int, count: int, hazards: int, show: Callable[[str], None]
) -> None:
    """The event log, the team and its hazards, straight through the repositories."""
    for i in range(robots):
        kind = RobotKind.WARDEN if i % WARDEN_EVERY == 0 else RobotKind.EXPLORER
        await repos.hazards.register_robot(robot_name(i), kind.value)
    now = datetime.now(timezone.utc)
    written = 0
    for batch in seeded_events(robots, count, hazards, now):
        await repos.events.write_events(batch)
        found = [NewHazard.of(record) for record in batch if record.type == EventType.HAZARD.value]
        if found:
            await repos.hazards.hold_hazards(found)
        written += len(batch)
        show(f"event log: {written:,} of {count:,} events")
    held = await repos.hazards.held_hazards()
    await repos.hazards.mark_announced([h for h in held if h.hazard_id % 5], now)
    wardens = [robot_name(i) for i in range(0, robots, WARDEN_EVERY)]
    for done, h in enumerate(held):
        step, warden = h.hazard_id % 5, wardens[h.hazard_id % len(wardens)]
        for action, from_step in ((repos.hazards.claim, 2), (repos.hazards.mark_reached, 3)):
            if step >= from_step:
                await action(h.mission_id, h.hazard_id, warden, now)
        if step == 4:
            await repos.hazards.mark_cleared(h.mission_id, h.hazard_id, warden, now)
        if done % 500 == 0:
            show(f"hazards: {done:,} of {len(held):,} taken to their state")


async def page_times(base: str, renders: int, show: Callable[[str], None]) -> dict[str, list[float]]:
    """Each page an administrator may open, fetched ``renders`` times (after one not counted): ms each."""
    pages = [page for page in PAGES if page.admits(UserRole.ADMIN) and "{" not in page.path]
    times: dict[str, list[float]] = {}
    client = await logged_in(base, 1)
    try:
        for page in pages:
            show(f"rendering {page.title}")
            (await client.get(page.path)).raise_for_status()
            times[page.name] = []
            for _ in range(renders):
                started = time.perf_counter()
                reply = await client.get(page.path)
                times[page.name].append((time.perf_counter() - started) * 1000)
                assert reply.status_code == 200, f"{page.path}: {reply.status_code}"
        for minutes in WINDOWS:  # the live map's trails, sampled when the window holds too many poses
            name = f"trails {minutes} min"
            show(f"fetching {name}")
            times[name] = []
            for _ in range(renders + 1):
                started = time.perf_counter()
                reply = await client.get("/console/map/trails", params={"minutes": minutes})
                times[name].append((time.perf_counter() - started) * 1000)
                assert reply.status_code == 200, f"{name}: {reply.status_code}"
            del times[name][0]
    finally:
        await client.aclose()
    return times


def renders(context: Context, args: argparse.Namespace) -> dict[str, Any]:
    with context.bus() as bus:
        started = time.monotonic()
        bus.with_store(lambda repos: seed(repos, args.robots, args.messages, args.hazards, context.show))
        write_recording(bus, args.messages, context.show)
        seeded_s = time.monotonic() - started
        with api_process(bus, ADMIN, PASSWORD) as (base, _):
            times = asyncio.run(page_times(base, args.renders, context.show))
            drawn = browser_times(base, ADMIN, PASSWORD, args.browser_renders, context.show)
        figures: Figures = {"seeding s": seeded_s}
        for name, each in {**times, **drawn}.items():
            figures[f"{name} render median ms"] = statistics.median(each)
            figures[f"{name} render p95 ms"] = percentile(each, 95)
        console.print(part_table("renders", figures))
        for name, each in drawn.items():
            if ": " in name:  # a stage of a page, not the page drawn
                continue
            p95 = percentile(each, 95)
            verdict = "met" if p95 < DRAWN_TARGET_MS else "NOT met"
            console.print(f"{name}: p95 {p95:,.0f} ms, target under {DRAWN_TARGET_MS:,} ms: {verdict}")
    return {"figures": figures, "pages": list(times)}


def part_table(title: str, figures: Figures) -> Table:
    table = Table(title=f"{title} (load average {load_average()})")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for name, value in figures.items():
        table.add_row(name, f"{value:,.2f}" if isinstance(value, float) else f"{value:,}")
    return table


def main() -> None:
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.settings import load_settings
    from fleetbus_dev.fallback import resolve_broker

    parser = argparse.ArgumentParser(
        description="The operator console under a team's traffic (a few minutes; --help's end says how).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    parser.add_argument("--robots", type=int, default=100, help="robots, each a status and a pose a second")
    parser.add_argument("--dashboards", type=int, default=20, help="open dashboards (SSE streams)")
    parser.add_argument("--maps", type=int, default=20, help="open live maps (SSE streams)")
    parser.add_argument(
        "--nice",
        type=int,
        default=FLEET_NICE,
        help=f"the robots' niceness ({FLEET_NICE}: on what the server leaves, as robots elsewhere; 0: equal)",
    )
    parser.add_argument("--seconds", type=float, default=60, help="how long the latency is measured")
    parser.add_argument("--reconnects", type=int, default=1000, help="dashboard reconnections")
    parser.add_argument("--hazards", type=int, default=10_000, help="hazards in the store for the renders")
    parser.add_argument("--messages", type=int, default=1_000_000, help="events and recorded messages")
    parser.add_argument("--renders", type=int, default=50, help="fetches of each page")
    parser.add_argument(
        "--browser-renders", type=int, default=10, help="the dashboard and the map drawn in chromium"
    )
    parser.add_argument(
        "--poll-s", type=float, help="the console's FLEETBUS_CONSOLE_POLL_S (default: the setting's own)"
    )
    parser.add_argument("--skip", choices=("live", "renders"), help="leave out one part")
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    result: dict[str, Any] = {
        "command": "python -m bench.console " + " ".join(sys.argv[1:]),
        "load at the start": load_average(),
    }
    with (
        # a broker taking 100 robots' accounts down on a busy machine may take its time
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url, timeout=120) as api,
        Progress(console=console, transient=True) as progress,
    ):
        task = progress.add_task("console", total=None)
        context = Context(endpoint, api, show=lambda text: progress.update(task, description=text))
        if args.skip != "live":
            result["live"] = live(context, args)
            result["load after live"] = load_average()
        if args.skip != "renders":
            result["renders"] = renders(context, args)
            result["load after renders"] = load_average()
    if "renders" in result and "hazards" not in result["renders"]["pages"]:
        console.print(
            f"no hazards page in this console yet: rendered {', '.join(result['renders']['pages'])}"
        )
    console.print(f"wrote {save(args.out, 'console', result)}")


if __name__ == "__main__":
    main()
