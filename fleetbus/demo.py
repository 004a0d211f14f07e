"""The demo scenario: an explorer publishes hazards, telemetry and a map; two wardens listen.

It runs the real parts: the broker, per-robot accounts, the worker and the store, in a virtual
host of its own (``fleetbus-demo``) so it never touches a real team's queues.
"""

from __future__ import annotations

import asyncio
import base64
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from typing import Any

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from broker.accounts import Role, fresh_vhost, provision_account
from broker.dead_letter_queue import peek_dead_letters
from broker.endpoint import BrokerEndpoint
from broker.management import ManagementAPI
from fleetbus.config import Settings
from fleetbus.registry import register_robot
from publishers.client import RobotClient
from schemas.routing import EventType, RobotKind
from workers.store import run_with_store
from workers.store.base import EventQuery
from workers.thread import WorkerThread

DEMO_VHOST = "fleetbus-demo"
EXPLORER = "demo-explorer1"
WARDENS = ("demo-warden1", "demo-warden2")
TEAM = ((EXPLORER, RobotKind.EXPLORER), *((warden, RobotKind.WARDEN) for warden in WARDENS))


@dataclass
class DemoReport:
    published: dict[str, int] = field(default_factory=dict)
    stored: dict[str, int] = field(default_factory=dict)
    delivered: dict[str, dict[str, int]] = field(default_factory=dict)
    dead_letters: int = 0
    seconds: float = 0.0


def demo_hazard(i: int, start: datetime) -> dict[str, Any]:
    return {
        "pose": {"x": 2.66 + i, "y": 1.22, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
        "frame_id": "map",
        "description": ["Fire", "Gas leak", "Debris", "Flooding"][i % 4],
        "detected_at": (start + timedelta(seconds=i)).isoformat(),
    }


def demo_map(created: datetime, width: int = 200, height: int = 150) -> dict[str, Any]:
    header = f"P5\n{width} {height}\n255\n".encode()
    pixels = bytes(
        0 if (x in (0, width - 1) or y in (0, height - 1)) else 254
        for y in range(height)
        for x in range(width)
    )
    return {
        "pgm": base64.b64encode(header + pixels).decode(),
        "metadata": {
            "resolution": 0.11,
            "origin": [2.1, 3.5, 0.0],
            "occupied_thresh": 0.65,
            "free_thresh": 0.196,
            "negate": 0,
        },
        "created_at": created.isoformat(),
    }


def demo_status(i: int) -> dict[str, Any]:
    return {
        "battery_percent": 100 - i,
        "pose": {"x": i * 0.5, "y": 1.0},
        "current_waypoint": f"wp{i}",
        "processing_rate_hz": 9.5,
    }


def _count_since(settings: Settings, since: datetime) -> dict[str, int]:
    records = run_with_store(
        settings, lambda store: store.find_events(EventQuery(since=since, robot_id=EXPLORER))
    )
    counts: dict[str, int] = {}
    for record in records:
        counts[record.type] = counts.get(record.type, 0) + 1
    return counts


def run_demo(
    settings: Settings, endpoint: BrokerEndpoint, console: Console, hazards: int = 20, telemetry: int = 20
) -> DemoReport:
    report = DemoReport()
    started = time.monotonic()
    run_start = datetime.now(timezone.utc)
    demo_settings = replace(settings, data_dir=settings.data_dir / "demo")
    demo_settings.data_dir.mkdir(parents=True, exist_ok=True)
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        Progress(console=console, transient=True) as progress,
    ):
        step = progress.add_task("setting up accounts", total=None)
        admin_url = fresh_vhost(api, endpoint.amqp_url, DEMO_VHOST)
        accounts = {
            name: asyncio.run(provision_account(admin_url, api, name, Role.ROBOT, kind, rotate=True))
            for name, kind in TEAM
        }
        demo_settings = replace(demo_settings, amqp_url=admin_url, management_url=endpoint.management_url)
        for name, kind in TEAM:
            register_robot(demo_settings, name, kind)
        clients = {
            name: RobotClient(account.amqp_url, state_dir=demo_settings.robots_dir)
            for name, account in accounts.items()
        }
        for client in clients.values():
            client.connect()
        progress.update(step, description="starting the worker")
        with WorkerThread(demo_settings, replace(endpoint, amqp_url=admin_url)):
            for warden in WARDENS:
                clients[warden].publish(EventType.LOCALISATION, {"localised": True})
            progress.update(step, description=f"{EXPLORER} publishing")
            items: list[tuple[EventType, Any]] = [
                (EventType.HAZARD, demo_hazard(i, run_start)) for i in range(hazards)
            ]
            items += [(EventType.STATUS, demo_status(i)) for i in range(telemetry)]
            items.append((EventType.MAP, demo_map(run_start)))
            sent = clients[EXPLORER].publish_many(items)
            for event in sent:
                report.published[event.type.value] = report.published.get(event.type.value, 0) + 1
            expected = report.published.get("hazard", 0) + report.published.get("map", 0)
            for warden in WARDENS:
                receiving = progress.add_task(f"{warden} receiving", total=expected)
                got: dict[str, int] = {}
                for note in clients[warden].notifications(timeout=30):
                    got[note.topic.value] = got.get(note.topic.value, 0) + 1
                    progress.advance(receiving)
                    if sum(got.values()) == expected:
                        break
                report.delivered[warden] = got
            progress.update(step, description="waiting for the store")
            deadline = time.monotonic() + 30
            while sum(report.stored.values()) < len(sent) and time.monotonic() < deadline:
                report.stored = _count_since(demo_settings, run_start)
        for client in clients.values():
            client.close()
        report.dead_letters = len(peek_dead_letters(admin_url))
        for name in accounts:  # broker users are global: leave none behind to clash with a real team's
            api.delete_user(name)
    report.seconds = time.monotonic() - started
    return report


def report_table(report: DemoReport) -> Table:
    table = Table(title=f"fleetbus demo ({report.seconds:.1f} s)")
    table.add_column("event type")
    table.add_column(f"published by {EXPLORER}", justify="right")
    table.add_column("stored", justify="right")
    for warden in report.delivered:
        table.add_column(f"delivered to {warden}", justify="right")
    for event_type in sorted(report.published):
        row = [event_type, str(report.published[event_type]), str(report.stored.get(event_type, 0))]
        row += [str(got.get(event_type, 0)) for got in report.delivered.values()]
        table.add_row(*row)
    table.caption = f"dead letters: {report.dead_letters}; telemetry is stored but not sent to wardens"
    return table
