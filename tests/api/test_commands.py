"""The commands people run against the service layer: the first admin made on the server, the API
served by uvicorn over real HTTP, a login from the shell that keeps the broker URL."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator

import httpx
import pytest
from typer.testing import CliRunner

from fleetbus.cli import app
from fleetbus.publishers.tls import blocking_connection
from tests.api.server import api_process, free_port, wait_until_serving
from tests.support import Bus

PASSWORD = "first admin password"


@pytest.fixture
def env(bus: Bus) -> Iterator[dict[str, str]]:
    environment = bus.worker_env()
    environment.pop("FLEETBUS_API_SECRET", None)  # the secret the server keeps itself
    yield environment
    for name in ("admin", "ops1"):
        bus.api.delete_user(name)


def test_create_admin_serve_and_log_in_from_the_shell(bus: Bus, env: dict[str, str]) -> None:
    runner = CliRunner()
    created = runner.invoke(
        app, ["api", "create-admin", "admin", "--password-stdin"], input=PASSWORD + "\n", env=env
    )
    assert created.exit_code == 0, created.output
    again = runner.invoke(
        app, ["api", "create-admin", "admin", "--password-stdin"], input=PASSWORD + "\n", env=env
    )
    assert again.exit_code == 1 and "user 'admin' exists" in again.output
    short = runner.invoke(app, ["api", "create-admin", "root2", "--password-stdin"], input="short\n", env=env)
    assert short.exit_code == 1 and "at least 10 characters" in short.output

    port = free_port()
    log = open(bus.settings.data_dir / "fleetbus.api.log", "wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "fleetbus", "api", "--port", str(port)],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_serving(server, base, log.name)
        # making a user makes its broker account too: on a loaded machine, longer than httpx's 5 s
        token = httpx.post(
            f"{base}/auth/token", data={"username": "admin", "password": PASSWORD}, timeout=60
        ).json()["access_token"]
        made = httpx.post(
            f"{base}/users",
            timeout=60,
            json={"name": "ops1", "password": "operator password", "role": "operator"},
            headers={"Authorization": f"Bearer {token}"},
        )
        assert made.status_code == 201, made.text
        login = runner.invoke(
            app,
            ["api", "login", "ops1", "--api", base, "--password-stdin"],
            input="operator password\n",
            env=env,
        )
        assert login.exit_code == 0, login.output
        assert "logged in as ops1 (operator)" in login.output
        saved = bus.settings.accounts_dir / "ops1.url"
        assert oct(saved.stat().st_mode & 0o777) == "0o600"
        connection = blocking_connection(saved.read_text().strip())
        connection.channel().queue_declare("ops1.stream", passive=True)
        connection.close()
        wrong = runner.invoke(
            app, ["api", "login", "ops1", "--api", base, "--password-stdin"], input="nope\n", env=env
        )
        assert wrong.exit_code == 1 and "401: wrong user name or password" in wrong.output
    finally:
        server.terminate()
        server.wait(30)
        log.close()
    assert oct((bus.settings.api_dir / "secret").stat().st_mode & 0o777) == "0o600"


def test_a_proxys_forwarded_https_is_believed_only_from_the_addresses_given(bus: Bus) -> None:
    """Behind a proxy that adds TLS the console's cookies are marked Secure: `fleetbus api` believes
    X-Forwarded-Proto from this machine by default, and from --forwarded-allow-ips when given."""

    def cookie_behind_tls(base: str) -> str:
        login = httpx.get(f"{base}/console/login", headers={"X-Forwarded-Proto": "https"}, timeout=30)
        assert login.status_code == 200, login.text
        return login.headers["set-cookie"].lower()

    with api_process(bus, None) as (base, _):
        assert "; secure" in cookie_behind_tls(base)
    with api_process(bus, None, options=("--forwarded-allow-ips", "192.0.2.10")) as (base, _):
        assert "; secure" not in cookie_behind_tls(base), "a header from an address not given"
