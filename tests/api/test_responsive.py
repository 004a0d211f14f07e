"""The API stays responsive, over real HTTP to `fleetbus api` in its own process: password hashes
are computed off the event loop; failed logins are limited per account and per client address
(429 with Retry-After) without locking anyone out for good; the API secret is made atomically."""

from __future__ import annotations

import asyncio
import multiprocessing
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import httpx
import psutil
import pytest
from argon2 import PasswordHasher

from fleetbus.api.services.security import master_secret
from fleetbus.settings import load_settings
from tests.api.server import api_process, api_server
from tests.support import Bus, wait_for

ADMIN = "admin-limits"
PASSWORD = "the admin's password"
WRONG = "not the password"
#: CPU the API server spends on a login before the GET is sent: its password check is under way.
CHECKING_CPU_S = 0.3


def client(base: str, address: str) -> httpx.Client:
    """A client whose connections come from ``address`` (any of 127.0.0.0/8 is this machine)."""
    return httpx.Client(base_url=base, transport=httpx.HTTPTransport(local_address=address), timeout=60)


def log_in(http: httpx.Client, name: str, password: str) -> httpx.Response:
    return http.post("/auth/token", data={"username": name, "password": password})


@pytest.fixture
def strict_api(bus: Bus) -> Iterator[str]:
    limits = {
        "FLEETBUS_API_ACCOUNT_FAILURES": "3 per 60 seconds",
        "FLEETBUS_API_ADDRESS_FAILURES": "5 per 60 seconds",
    }
    with api_server(bus, ADMIN, PASSWORD, **limits) as base:
        yield base


def test_failed_logins_are_limited_per_account_and_per_address(strict_api: str) -> None:
    with client(strict_api, "127.0.0.2") as guesser, client(strict_api, "127.0.0.3") as owner:
        for _ in range(3):
            assert log_in(guesser, ADMIN, WRONG).status_code == 401
        refused = log_in(guesser, ADMIN, PASSWORD)  # even the right password: not checked now
        assert refused.status_code == 429, refused.text
        assert refused.json()["detail"].startswith(
            f"too many failed logins to {ADMIN} from 127.0.0.2; try again in"
        )
        assert 1 <= int(refused.headers["Retry-After"]) <= 60

        assert log_in(owner, ADMIN, PASSWORD).status_code == 200, "the owner, elsewhere, is not locked out"

        for name in ("nobody1", "nobody2"):  # the guesser's 4th and 5th failure, on other accounts
            assert log_in(guesser, name, WRONG).status_code == 401
        spread = log_in(guesser, "nobody3", WRONG)
        assert spread.status_code == 429 and spread.json()["detail"].startswith(
            "too many failed logins from 127.0.0.2;"
        )
        assert log_in(owner, ADMIN, PASSWORD).status_code == 200


def test_a_lockout_ends_by_itself_and_a_success_clears_the_count(bus: Bus) -> None:
    with (
        api_server(bus, ADMIN, PASSWORD, FLEETBUS_API_ACCOUNT_FAILURES="2 per 3 seconds") as base,
        client(base, "127.0.0.2") as admin,
    ):
        for _ in range(2):
            assert log_in(admin, ADMIN, WRONG).status_code == 401
        locked = log_in(admin, ADMIN, PASSWORD)
        assert locked.status_code == 429 and int(locked.headers["Retry-After"]) <= 3
        reply = wait_for(
            lambda: (r := log_in(admin, ADMIN, PASSWORD)).status_code == 200 and r,
            timeout=30,
            what="the administrator's login to be accepted again",
        )
        assert reply.json()["user"]["name"] == ADMIN
        assert log_in(admin, ADMIN, WRONG).status_code == 401
        assert log_in(admin, ADMIN, PASSWORD).status_code == 200, "the success cleared the earlier failure"


async def _log_in_then_get(base: str, server: psutil.Process, name: str, token: str) -> tuple[float, float]:
    """A login of ``name``, then an authenticated GET sent once the server has spent CPU on checking
    its password (nothing else in it works meanwhile): when each answered."""
    async with httpx.AsyncClient(base_url=base, timeout=120) as http:

        async def log_in_once() -> float:
            reply = await http.post("/auth/token", data={"username": name, "password": PASSWORD})
            assert reply.status_code == 200, reply.text
            return time.monotonic()

        def cpu() -> float:
            times = server.cpu_times()
            return times.user + times.system

        async def get_once() -> float:
            before, deadline = cpu(), time.monotonic() + 60
            while cpu() - before < CHECKING_CPU_S:  # the login's password is being checked
                assert time.monotonic() < deadline, "the server never began checking the password"
                await asyncio.sleep(0.02)
            reply = await http.get("/users/me", headers={"Authorization": f"Bearer {token}"})
            assert reply.status_code == 200, reply.text
            return time.monotonic()

        logged_in, got = await asyncio.gather(log_in_once(), get_once())
    return logged_in, got


def test_an_authenticated_get_answers_while_a_password_is_being_checked(bus: Bus) -> None:
    """A login whose stored hash has a high time cost keeps argon2 busy for over a second; a GET sent
    meanwhile answers first, which it could not while hashes were computed on the event loop."""
    slow_hash = PasswordHasher(time_cost=60).hash(PASSWORD)  # about 2.6 s to check here
    with api_process(bus, ADMIN, PASSWORD) as (base, server), httpx.Client(base_url=base, timeout=60) as http:
        token = log_in(http, ADMIN, PASSWORD).json()["access_token"]
        bus.accounts.append("slowpoke")
        body = {"name": "slowpoke", "password": PASSWORD, "role": "client"}
        made = http.post("/users", json=body, headers={"Authorization": f"Bearer {token}"})
        assert made.status_code == 201, made.text
        bus.with_store(
            lambda store: store.users.update_user(
                "slowpoke", datetime.now(timezone.utc), password_hash=slow_hash
            )
        )
        logged_in, got = asyncio.run(_log_in_then_get(base, psutil.Process(server.pid), "slowpoke", token))
    assert got < logged_in, "the GET waited for the password check of the login sent before it"


def _secret_of(data_dir: str, barrier: Any) -> bytes:
    settings = load_settings({"FLEETBUS_DATA_DIR": data_dir})
    barrier.wait()
    return master_secret(settings)


def _race(args: tuple[list[str], Any, Any]) -> None:
    data_dirs, barrier, results = args
    for data_dir in data_dirs:
        results.put((data_dir, _secret_of(data_dir, barrier)))


def test_api_processes_started_at_once_end_with_the_same_secret(tmp_path: Path) -> None:
    processes, rounds = 6, 25
    data_dirs = [str(tmp_path / f"round{n}") for n in range(rounds)]
    context = multiprocessing.get_context("spawn")
    barrier = context.Barrier(processes)
    results = context.Queue()
    racers = [context.Process(target=_race, args=((data_dirs, barrier, results),)) for _ in range(processes)]
    for racer in racers:
        racer.start()
    seen: dict[str, set[bytes]] = {}
    for _ in range(processes * rounds):
        data_dir, secret = results.get(timeout=120)
        seen.setdefault(data_dir, set()).add(secret)
    for racer in racers:
        racer.join(60)
        assert racer.exitcode == 0
    different = {Path(d).name: len(s) for d, s in seen.items() if len(s) != 1}
    assert different == {}, f"rounds where the processes ended with different secrets: {different}"
    assert all(len(next(iter(s))) >= 48 for s in seen.values()), "an empty or partial secret was read"
    for data_dir in data_dirs:
        assert [p.name for p in (Path(data_dir) / "api").iterdir()] == ["secret"], "a draft was left behind"


def test_logins_sent_at_once_are_limited_as_if_sent_one_after_another(strict_api: str) -> None:
    """The attempts whose passwords are being checked count against the limit: ten guesses sent
    at once get no more password checks than three sent in turn (the rest are answered 429)."""

    async def guesses() -> list[int]:
        transport = httpx.AsyncHTTPTransport(local_address="127.0.0.4")
        async with httpx.AsyncClient(base_url=strict_api, transport=transport, timeout=60) as http:
            data = {"username": ADMIN, "password": WRONG}
            answers = await asyncio.gather(*(http.post("/auth/token", data=data) for _ in range(10)))
        return sorted(answer.status_code for answer in answers)

    assert asyncio.run(guesses()) == [401] * 3 + [429] * 7


def test_logins_that_succeed_sent_at_once_all_go_through(strict_api: str) -> None:
    """No more passwords are checked at once than the limit has room for, and a login beyond them
    waits for one to end rather than being refused: ten right passwords at once all log in."""

    async def logins() -> list[int]:
        transport = httpx.AsyncHTTPTransport(local_address="127.0.0.5")
        async with httpx.AsyncClient(base_url=strict_api, transport=transport, timeout=60) as http:
            data = {"username": ADMIN, "password": PASSWORD}
            answers = await asyncio.gather(*(http.post("/auth/token", data=data) for _ in range(10)))
        return [answer.status_code for answer in answers]

    assert asyncio.run(logins()) == [200] * 10
