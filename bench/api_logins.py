"""The API under a burst of logins: a cheap authenticated GET while 20 logins run at once.

    .venv/bin/python -m bench.api_logins [--gets 300] [--runs 3]

`fleetbus api` is served by uvicorn in a process of its own, on its own virtual host and SQLite
store; this process is the client (httpx on asyncio). Each login checks an argon2id hash, tens of
milliseconds of CPU; the API computes them on ``FLEETBUS_API_HASH_THREADS`` threads (1), never on
its event loop, so ``GET /users/me`` (a token check and one store read) need not wait behind them.
Figures: the GET's latency with no login running, then while 20 clients log in again and again,
and how many logins per second went through meanwhile.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from dataclasses import dataclass, field

import httpx
from rich.console import Console
from rich.table import Table

from bench.scenario import Context, Figures
from tests.api.server import api_server

LOGINS = 20
ADMIN = "bench-api-admin"
PASSWORD = "bench admin password"


@dataclass
class Burst:
    """What one burst measured; each list in completion order."""

    get_ms: list[float] = field(default_factory=list)
    login_ms: list[float] = field(default_factory=list)
    seconds: float = 0.0


def percentile(values: list[float], fraction: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))]


async def measure(base: str, gets: int, logins: int) -> Burst:
    """``gets`` GETs one after another while ``logins`` clients each log in again and again."""
    burst = Burst()
    limits = httpx.Limits(max_connections=logins + 1, max_keepalive_connections=logins + 1)
    async with httpx.AsyncClient(base_url=base, timeout=120, limits=limits) as client:
        credentials = {"username": ADMIN, "password": PASSWORD}
        reply = await client.post("/auth/token", data=credentials)
        assert reply.status_code == 200, reply.text
        headers = {"Authorization": f"Bearer {reply.json()['access_token']}"}
        done = asyncio.Event()
        in_flight = asyncio.Semaphore(0)

        async def log_in_again_and_again() -> None:
            while not done.is_set():
                started = time.perf_counter()
                in_flight.release()
                reply = await client.post("/auth/token", data=credentials)
                assert reply.status_code == 200, reply.text
                burst.login_ms.append((time.perf_counter() - started) * 1000)

        clients = [asyncio.create_task(log_in_again_and_again()) for _ in range(logins)]
        for _ in range(logins):  # every client has sent its first login
            await in_flight.acquire()
        started = time.perf_counter()
        try:
            for _ in range(gets):
                sent = time.perf_counter()
                reply = await client.get("/users/me", headers=headers)
                assert reply.status_code == 200 and reply.json()["name"] == ADMIN, reply.text
                burst.get_ms.append((time.perf_counter() - sent) * 1000)
        finally:
            burst.seconds = time.perf_counter() - started
            done.set()
            await asyncio.gather(*clients)
    return burst


def figures(context: Context) -> Figures:
    gets = context.size(300, 100)
    # the administrator logs in again and again while its first token GETs: no bound ends that session
    unbounded = {"FLEETBUS_API_SESSIONS_PER_USER": "1000000"}
    with context.bus() as bus, api_server(bus, ADMIN, PASSWORD, **unbounded) as base:
        context.show("GET with no login running")
        idle = asyncio.run(measure(base, gets, 0))
        context.show(f"GET while {LOGINS} log in")
        busy = asyncio.run(measure(base, gets, LOGINS))
    return {
        "GET p99 ms, idle": percentile(idle.get_ms, 0.99),
        f"GET p50 ms, {LOGINS} logging in": statistics.median(busy.get_ms),
        f"GET p99 ms, {LOGINS} logging in": percentile(busy.get_ms, 0.99),
        "logins/s": len(busy.login_ms) / busy.seconds,
    }


def main() -> None:
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.settings import load_settings
    from fleetbus_dev.fallback import resolve_broker

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gets", type=int, default=300)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    endpoint = resolve_broker(load_settings(), start=True)
    runs: list[Figures] = []
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        context = Context(endpoint, api)
        context.size = lambda full, quick: args.gets  # type: ignore[method-assign]
        for _ in range(args.runs):
            runs.append(figures(context))
    table = Table(title=f"API under {LOGINS} concurrent logins, {args.runs} runs of {args.gets} GETs")
    for column in ("figure", "median", "runs"):
        table.add_column(column, justify="left" if column == "figure" else "right")
    for name in runs[0]:
        values = [run[name] for run in runs]
        table.add_row(name, f"{statistics.median(values):.1f}", ", ".join(f"{v:.1f}" for v in values))
    Console().print(table)


if __name__ == "__main__":
    main()
