"""`fleetbus api` served by uvicorn in a process of its own, over real HTTP (no TestClient)."""

from __future__ import annotations

import ssl
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import httpx

from fleetbus_dev.local_node import choose_free_ports
from tests.support import Bus, wait_for


def free_port() -> int:
    """A free port below the ephemeral range: one the kernel hands out (port 0) may be taken as an
    outgoing connection's source port before the server binds it."""
    return choose_free_ports(1)[0]


def wait_until_serving(
    server: subprocess.Popen[bytes], base: str, log: str, verify: ssl.SSLContext | bool = True
) -> None:
    """Until `fleetbus api` at ``base`` answers ``GET /health`` (one HTTP client for every try:
    each new one loads the TLS certificates); fail if it exits first."""
    with httpx.Client(base_url=base, timeout=2, verify=verify) as http:

        def healthy() -> bool:
            if server.poll() is not None:
                raise AssertionError(f"`fleetbus api` exited with {server.returncode}: see {log}")
            try:
                return http.get("/health").status_code == 200
            except httpx.HTTPError:
                return False

        wait_for(healthy, timeout=60, what="the API answering")


@contextmanager
def api_server(bus: Bus, admin: str, password: str, **settings: str) -> Iterator[str]:
    """`fleetbus api` served by uvicorn in its own process on the bus (as administrator), with
    ``settings`` (``FLEETBUS_...``) and the admin ``admin``; yields its base URL."""
    with api_process(bus, admin, password, **settings) as (base, _):
        yield base


@contextmanager
def api_process(
    bus: Bus,
    admin: str | None,
    password: str = "",
    ca: Path | None = None,
    options: Sequence[str] = (),
    **settings: str,
) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """:func:`api_server`, yielding its base URL and its process (to read its memory, say); with
    ``ca``, served over HTTPS (``--tls``) with a certificate that CA signed; with no ``admin``,
    no account is made (a test of the listener alone); ``options``: more of `fleetbus api`'s."""
    env = {**bus.worker_env(), **settings}
    env.pop("FLEETBUS_API_SECRET", None)  # the secret the server keeps itself
    fleetbus = [sys.executable, "-m", "fleetbus", "api"]
    if admin is not None:
        bus.api.delete_user(admin)  # broker users are broker-wide: one left by an aborted run
        made = subprocess.run(
            [*fleetbus, "create-admin", admin, "--password-stdin"],
            input=password + "\n",
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert made.returncode == 0, made.stderr
    port = free_port()
    log = open(bus.settings.data_dir / f"api-{port}.log", "wb")
    tls = ["--tls"] if ca else []
    server = subprocess.Popen(
        [*fleetbus, "--port", str(port), *tls, *options], env=env, stdout=log, stderr=subprocess.STDOUT
    )
    base = f"{'https' if ca else 'http'}://127.0.0.1:{port}"
    try:
        wait_until_serving(server, base, log.name, ssl.create_default_context(cafile=str(ca)) if ca else True)
        yield base, server
    finally:
        server.terminate()
        server.wait(30)
        log.close()
        if admin is not None:
            bus.api.delete_user(admin)
