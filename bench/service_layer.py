"""What the service layer's own work costs: logging in, an authorised request, a mount cycle.

    .venv/bin/python -m bench.service_layer [--rounds 50] [--runs 3]

One app (the real FastAPI app in-process through its ASGI client, no network), its own virtual
host and SQLite store. Medians of ``--runs`` runs of ``--rounds`` each:
  login            POST /auth/token (argon2id verification dominates)
  authorised GET   GET /missions with a token (JWT check, role from the store, one query)
  mount + unmount  POST /mounts then DELETE /mounts/{robot}: booking in the store, two bindings
                   made and removed through the management API, two channel changes recorded
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from fleetbus.api.app import create_app
from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker

BENCH_VHOST = "fleetbus-bench-api"
PASSWORD = "bench password 1"
PLAN = {"geofence": {"polygon": [{"x": 0, "y": 0}, {"x": 9, "y": 0}, {"x": 0, "y": 9}]}}
console = Console()


def timed(rounds: int, work: Callable[[], None]) -> float:
    started = time.perf_counter()
    for _ in range(rounds):
        work()
    return rounds / (time.perf_counter() - started)


def main() -> None:
    with warnings.catch_warnings():  # starlette asks for its httpx fork; plain httpx works
        warnings.simplefilter("ignore")
        from fastapi.testclient import TestClient

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=50)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    names = ("bench-ops", "bench-client", "bench-super", "bench-robot")
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        tempfile.TemporaryDirectory() as tmp,
    ):
        admin_url = fresh_vhost(api, endpoint.amqp_url, BENCH_VHOST)
        # one user logs in again and again while its first token is used: no bound ends that session
        settings = load_settings().updated(
            data_dir=Path(tmp), amqp_url=admin_url, mongodb_url=None, api_sessions_per_user=1_000_000
        )
        app = create_app(settings, admin_url, endpoint.management_url)
        try:
            with TestClient(app) as client:
                service = app.state.service
                for name in names:
                    api.delete_user(name)
                roles = (UserRole.OPERATOR, UserRole.CLIENT, UserRole.SUPERVISOR, UserRole.ROBOT)
                for name, role in zip(names, roles, strict=True):
                    kind = RobotKind.EXPLORER if role is UserRole.ROBOT else None
                    client.portal.call(
                        lambda n=name, r=role, k=kind: service.accounts.create(n, PASSWORD, r, k, "bench")
                    )
                store, now = service.store, datetime.now(timezone.utc)
                mission = client.portal.call(
                    lambda: store.create_mission("survey", "bench", "bench-client", PLAN, now)
                )
                client.portal.call(
                    lambda: store.transition_mission(
                        mission.mission_id, MissionState.PLANNING, MissionState.IN_PROGRESS, "bench", now
                    )
                )

                def login() -> None:
                    assert (
                        client.post(
                            "/auth/token", data={"username": "bench-ops", "password": PASSWORD}
                        ).status_code
                        == 200
                    )

                token = client.post(
                    "/auth/token", data={"username": "bench-ops", "password": PASSWORD}
                ).json()["access_token"]
                headers = {"Authorization": f"Bearer {token}"}

                def authorised() -> None:
                    assert client.get("/missions", headers=headers).status_code == 200

                def mount_cycle() -> None:
                    body = {"robot": "bench-robot", "mission_id": mission.mission_id}
                    assert client.post("/mounts", json=body, headers=headers).status_code == 201
                    assert client.delete("/mounts/bench-robot", headers=headers).status_code == 200

                scenarios = {
                    "login": login,
                    "authorised GET /missions": authorised,
                    "mount + unmount": mount_cycle,
                }
                results: dict[str, list[float]] = {name: [] for name in scenarios}
                with Progress(console=console, transient=True) as progress:
                    task = progress.add_task("measuring", total=args.runs * len(scenarios))
                    for _ in range(args.runs):
                        for name, work in scenarios.items():
                            results[name].append(timed(args.rounds, work))
                            progress.advance(task)
        finally:
            for name in names:
                api.delete_user(name)
            api.delete_vhost(BENCH_VHOST)
    table = Table(title=f"service layer, {args.runs} runs of {args.rounds} (per second)")
    for column in ("scenario", "median /s", "spread", "median ms each"):
        table.add_column(column, justify="left" if column == "scenario" else "right")
    for name, rates in results.items():
        median = statistics.median(rates)
        table.add_row(name, f"{median:,.0f}", f"{min(rates):,.0f}-{max(rates):,.0f}", f"{1000 / median:.1f}")
    console.print(table)


if __name__ == "__main__":
    main()
