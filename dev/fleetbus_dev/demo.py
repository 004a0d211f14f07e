"""The demo scenario, with the real parts (broker, per-robot accounts, worker, store).

An explorer, two wardens and a guide: hazards detected before the wardens localise are held, then
announced in order; wardens claim and clear them; the explorer sends a large map that a warden
fetches back byte for byte; the guide hears beacons and gets its next goal. It runs in a virtual
host of its own (``fleetbus-demo``) with a store of its own (``$FLEETBUS_DATA_DIR/demo``, made anew
each run), so it never touches a real team's queues or data.
"""

from __future__ import annotations

import asyncio
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from typing import Any, TypeVar

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from fleetbus.api.services.accounts import open_accounts
from fleetbus.broker.accounts import (
    RECORDER_USER,
    SERVICE_USER,
    fresh_vhost,
    kept_password,
    kept_password_file,
    save_secret,
)
from fleetbus.broker.dead_letter_queue import peek_dead_letters
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.fleet import NewRobot
from fleetbus.broker.management import ManagementAPI
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.rpc import ServiceRefused
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.settings import Settings
from fleetbus.workers.setup import set_up_service
from fleetbus.workers.store import open_recording_store, run_with_repositories
from fleetbus.workers.store.base import EventQuery
from fleetbus.workers.store.beacons import Beacon
from fleetbus.workers.store.hazards import HazardState
from fleetbus.workers.store.recordings import RecordQuery
from fleetbus_dev.recorder_thread import RecorderThread
from fleetbus_dev.worker_thread import WorkerThread

T = TypeVar("T")
DEMO_VHOST = "fleetbus-demo"
EXPLORER = "demo-explorer1"
WARDENS = ("demo-warden1", "demo-warden2")
GUIDE = "demo-guide1"
TEAM = (
    (EXPLORER, RobotKind.EXPLORER),
    *((warden, RobotKind.WARDEN) for warden in WARDENS),
    (GUIDE, RobotKind.GUIDE),
)
BEACONS = [
    Beacon("b1", 1.0, 2.0, "room 101"),
    Beacon("b2", 8.0, 3.0, "lab"),
    Beacon("b3", 4.0, 9.0, "stairs"),
]
MAP_YAML = {
    "resolution": 0.05,
    "origin": [-10.0, -10.0, 0.0],
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
    "negate": 0,
}


@dataclass
class DemoReport:
    steps: list[tuple[str, str]] = field(default_factory=list)
    published: dict[str, int] = field(default_factory=dict)
    stored: dict[str, int] = field(default_factory=dict)
    recorded: dict[str, int] = field(default_factory=dict)
    """The explorer's messages in the recording, by type."""
    delivered: dict[str, dict[str, int]] = field(default_factory=dict)
    dead_letters: int = 0
    seconds: float = 0.0
    ok: bool = True


def demo_hazard(i: int, start: datetime) -> dict[str, Any]:
    return {
        "pose": {"x": 2.66 + i, "y": 1.22, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
        "frame_id": "map",
        "description": ["Fire", "Gas leak", "Debris", "Flooding"][i % 4],
        "detected_at": (start + timedelta(seconds=i)).isoformat(),
    }


def demo_status(i: int) -> dict[str, Any]:
    return {
        "battery_percent": 100 - i,
        "pose": {"x": i * 0.5, "y": 1.0},
        "current_waypoint": f"wp{i}",
        "processing_rate_hz": 9.5,
    }


def demo_pgm(width: int, height: int) -> bytes:
    """A room: free space inside occupied walls."""
    wall, free = b"\x00", b"\xfe"
    inner = wall + free * (width - 2) + wall
    return f"P5\n{width} {height}\n255\n".encode() + wall * width + inner * (height - 2) + wall * width


def wait(condition: Callable[[], T], timeout: float = 30.0) -> T:
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise TimeoutError("the demo waited too long for the team")
        time.sleep(0.05)
    return value


class Scenario:
    def __init__(self, settings: Settings, clients: dict[str, RobotClient], report: DemoReport) -> None:
        self.settings = settings
        self.robots = clients
        self.report = report
        self.start = datetime.now(timezone.utc)

    def step(self, what: str, outcome: str, ok: bool = True) -> None:
        self.report.steps.append((what, outcome))
        self.report.ok &= ok

    def held_announced(self) -> tuple[int, int]:
        hazards = run_with_repositories(self.settings, lambda repos: repos.hazards.open_hazards("default"))
        held = sum(h.state is HazardState.HELD for h in hazards)
        return held, len(hazards) - held

    def receive(self, robot: str, count: int) -> list:
        notes = self.robots[robot].receive(count, timeout=60)
        for note in notes:
            got = self.report.delivered.setdefault(robot, {})
            got[note.topic.value] = got.get(note.topic.value, 0) + 1
        return notes

    def publish(self, robot: str, items: list[tuple[EventType, Any]]) -> None:
        for event in self.robots[robot].publish_many(items):
            if robot == EXPLORER:
                self.report.published[event.type.value] = self.report.published.get(event.type.value, 0) + 1

    def localisation_gate(self) -> None:
        self.publish(EXPLORER, [(EventType.HAZARD, demo_hazard(i, self.start)) for i in range(2)])
        counts = wait(lambda: (c := self.held_announced()) == (2, 0) and c)
        self.step(
            "2 hazards detected before the wardens localised", f"held {counts[0]}, announced {counts[1]}"
        )
        self.robots[WARDENS[0]].publish(EventType.LOCALISATION, {"localised": True})
        wait(
            lambda: (
                run_with_repositories(self.settings, lambda repos: repos.hazards.robots("warden"))[
                    0
                ].localised
            )
        )
        held, announced = self.held_announced()
        self.step(f"{WARDENS[0]} localised, {WARDENS[1]} not yet", f"held {held}, announced {announced}")
        self.robots[WARDENS[1]].publish(EventType.LOCALISATION, {"localised": True})
        ids = {warden: [n.hazard_id for n in self.receive(warden, 2)] for warden in WARDENS}
        held, announced = self.held_announced()
        fifo = all(got == [1, 2] for got in ids.values())
        self.step(
            "all wardens localised", f"held {held}, announced {announced}, in order {ids[WARDENS[0]]}", fifo
        )

    def live_traffic(self, hazards: int, telemetry: int) -> None:
        items = [(EventType.HAZARD, demo_hazard(i, self.start)) for i in range(2, 2 + hazards)]
        items += [(EventType.STATUS, demo_status(i)) for i in range(telemetry)]
        self.publish(EXPLORER, items)
        for warden in WARDENS:
            self.receive(warden, hazards)
        self.step(
            f"{hazards} more hazards and {telemetry} status messages",
            "hazards announced at once to both wardens",
        )

    def claims(self) -> None:
        first, second = (self.robots[w] for w in WARDENS)
        first.claim_hazard(1)
        try:
            second.claim_hazard(1)
            self.step(f"{WARDENS[1]} claims hazard 1 too", "accepted: wrong", ok=False)
        except ServiceRefused as refused:
            self.step(
                f"{WARDENS[0]}, then {WARDENS[1]} claim hazard 1",
                f"{WARDENS[1]} refused: {str(refused).split(': ', 1)[1]}",
            )
        first.hazard_reached(1)
        cleared = first.hazard_cleared(1)
        self.step(f"{WARDENS[0]} reaches and clears hazard 1", f"state {cleared['state']}")

    def map_transfer(self, width: int, height: int) -> None:
        image = demo_pgm(width, height)
        started = time.monotonic()
        for event in self.robots[EXPLORER].publish_map(image, MAP_YAML):
            self.report.published[event.type.value] = self.report.published.get(event.type.value, 0) + 1
        for warden in WARDENS:
            self.receive(warden, 1)
        fetched = self.robots[WARDENS[1]].fetch_map()
        seconds = time.monotonic() - started
        same = fetched.pgm == image and all(fetched.metadata[k] == v for k, v in MAP_YAML.items())
        verdict = "identical" if same else "DIFFERENT"
        self.step(
            f"{EXPLORER} sends a {width}x{height} map ({len(image) / 1e6:.1f} MB)",
            f"{WARDENS[1]} fetched version {fetched.version}, {verdict}, {seconds:.1f} s",
            same,
        )

    def beacons(self) -> None:
        run_with_repositories(self.settings, lambda repos: repos.beacons.put_beacons(BEACONS))
        guide = self.robots[GUIDE]
        guide.publish_many(
            [
                (EventType.BEACON, {"beacon_id": b, "rssi": r, "pose": {"x": x, "y": 2.0}})
                for b, r, x in (("b2", -70, 7.0), ("b1", -61, 1.5))
            ]
        )
        wait(
            lambda: (
                run_with_repositories(
                    self.settings, lambda repos: repos.events.count_events(EventType.BEACON.value, GUIDE)
                )
                >= 2
            )
        )
        stranded = [entry["label"] for entry in guide.stranded(minutes=5)]
        goal = guide.beacon_goal(minutes=5)
        self.step(
            f"{GUIDE} hears beacons b2 and b1",
            f"likely stranded: {', '.join(stranded)}; next goal: {goal['label']}",
        )


def count_stored(settings: Settings, since: datetime) -> dict[str, int]:
    records = run_with_repositories(
        settings, lambda repos: repos.events.find_events(EventQuery(since=since, robot_id=EXPLORER))
    )
    counts: dict[str, int] = {}
    for record in records:
        counts[record.type] = counts.get(record.type, 0) + 1
    return counts


def count_recorded(settings: Settings, types: list[str]) -> dict[str, int]:
    async def count() -> dict[str, int]:
        async with open_recording_store(settings) as store:
            return {t: len(await store.find_recorded(RecordQuery(t, robot_id=EXPLORER))) for t in types}

    return asyncio.run(count())


async def _provision_team(settings: Settings, admin_url: str, management_url: str) -> dict[str, str]:
    """The team's robots, recorded in the demo's account registry with their broker accounts (through
    the accounts service, as `fleetbus users add-many` makes them); their URLs by name. Broker users
    are broker-wide: those an earlier run left are re-keyed."""
    robots = [NewRobot(name, kind) for name, kind in TEAM]
    async with open_accounts(settings, admin_url, management_url) as opened:
        made = await opened.accounts.provision_robots(robots, "fleetbus demo", rotate=True)
    return {m.user.name: m.internal_url for m in made}


def run_demo(
    settings: Settings,
    endpoint: BrokerEndpoint,
    console: Console,
    hazards: int = 18,
    telemetry: int = 20,
    map_size: int = 2000,
) -> DemoReport:
    report = DemoReport()
    started = time.monotonic()
    # the demo's own embedded store, new each run, whatever store the team uses
    demo_settings = settings.updated(data_dir=settings.data_dir / "demo", mongodb_url=None)
    shutil.rmtree(demo_settings.data_dir, ignore_errors=True)
    demo_settings.data_dir.mkdir(parents=True)
    # The service accounts are the broker's, not the virtual host's: a worker of the team may be
    # logged in with them. The demo uses their kept passwords, so that it re-keys neither under it.
    for name in (SERVICE_USER, RECORDER_USER):
        if (password := kept_password(settings.accounts_dir, name)) is not None:
            save_secret(kept_password_file(demo_settings.accounts_dir, name), password)
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        Progress(console=console, transient=True) as progress,
    ):
        task = progress.add_task("setting up the team", total=7)
        admin_url = fresh_vhost(api, endpoint.amqp_url, DEMO_VHOST)
        demo_settings = demo_settings.updated(amqp_url=admin_url, management_url=endpoint.management_url)
        urls = asyncio.run(_provision_team(demo_settings, admin_url, endpoint.management_url))
        for name, _ in TEAM:
            run_with_repositories(
                demo_settings,
                lambda repos, name=name: repos.hazards.set_localised(name, False, datetime.now(timezone.utc)),
            )
        clients = {name: RobotClient(url, state_dir=demo_settings.robots_dir) for name, url in urls.items()}
        try:
            for client in clients.values():
                client.connect()
            service = asyncio.run(set_up_service(demo_settings, replace(endpoint, amqp_url=admin_url)))
            with (
                WorkerThread(demo_settings, service.service_url),
                RecorderThread(demo_settings, service.recorder_url),
            ):
                scenario = Scenario(demo_settings, clients, report)
                for description, act in (
                    ("localisation gate", scenario.localisation_gate),
                    ("live traffic", lambda: scenario.live_traffic(hazards, telemetry)),
                    ("claims", scenario.claims),
                    ("map transfer", lambda: scenario.map_transfer(map_size, map_size)),
                    ("beacons", scenario.beacons),
                ):
                    progress.update(task, description=description, advance=1)
                    act()
                progress.update(task, description="checking the store", advance=1)
                total = sum(report.published.values())
                report.stored = wait(
                    lambda: (
                        (c := count_stored(demo_settings, scenario.start)) and sum(c.values()) >= total and c
                    )
                )
                types = sorted(report.published)
                report.recorded = wait(
                    lambda: (c := count_recorded(demo_settings, types)) and sum(c.values()) >= total and c
                )
            report.dead_letters = len(peek_dead_letters(admin_url))
        finally:
            for client in clients.values():
                client.close()
            for name in urls:  # broker users are global: leave none behind to clash with a real team's
                api.delete_user(name)
    report.seconds = time.monotonic() - started
    return report


def steps_table(report: DemoReport) -> Table:
    table = Table(title="what happened")
    table.add_column("step")
    table.add_column("outcome")
    for what, outcome in report.steps:
        table.add_row(what, outcome)
    return table


def report_table(report: DemoReport) -> Table:
    table = Table(title=f"fleetbus demo ({report.seconds:.1f} s): what {EXPLORER} published")
    table.add_column("event type")
    table.add_column("published", justify="right")
    table.add_column("stored", justify="right")
    table.add_column("recorded", justify="right")
    for warden in WARDENS:
        table.add_column(f"delivered to {warden}", justify="right")
    for event_type in sorted(report.published):
        row = [event_type, str(report.published[event_type]), str(report.stored.get(event_type, 0))]
        row.append(str(report.recorded.get(event_type, 0)))
        row += [str(report.delivered.get(w, {}).get(event_type, 0)) for w in WARDENS]
        table.add_row(*row)
    table.caption = f"dead letters: {report.dead_letters}; telemetry is stored but not sent to wardens"
    return table
