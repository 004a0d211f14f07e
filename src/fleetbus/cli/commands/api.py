"""``fleetbus api``: serve the HTTP API; make the first admin; write the OpenAPI document; log in.

fleetbus api [--host 127.0.0.1] [--port 8000]   # serve (uvicorn) until Ctrl-C
fleetbus api create-admin NAME                  # the first admin, password typed twice
fleetbus api openapi openapi.json
fleetbus api login NAME [--api http://127.0.0.1:8000]   # keeps the broker URL for `tail`
fleetbus api end-sessions NAME                  # every login session of NAME ends
"""

from __future__ import annotations

import asyncio
import json
import ssl
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from fleetbus.broker.accounts import save_secret
from fleetbus.cli.context import actor, console, endpoint, fail, settings
from fleetbus.cli.services import with_services
from fleetbus.private_files import owner_only_umask
from fleetbus.schemas.roles import UserRole

# FastAPI, the service and httpx are imported by the commands that use them: every `fleetbus`
# command loads this module, and `fleetbus recorder run` must stay small (20 MB less resident).
app = typer.Typer(help="The HTTP API of the service layer (users, missions, mounts).")


@app.callback(invoke_without_command=True)
def serve(
    ctx: typer.Context,
    host: Annotated[str, typer.Option(help="address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port to listen on")] = 8000,
    tls: Annotated[
        bool,
        typer.Option(
            "--tls/--no-tls",
            help="serve HTTPS with the server certificate of FLEETBUS_TLS_CERT/_KEY "
            "(`fleetbus certs make` makes one)",
        ),
    ] = False,
    forwarded_allow_ips: Annotated[
        str | None,
        typer.Option(
            help="the reverse proxies whose X-Forwarded-For and X-Forwarded-Proto are believed "
            "(addresses or networks, comma-separated): the client's address, which the login limits "
            "count by, and HTTPS, which marks the console's cookies Secure. Default: this machine only "
            "(uvicorn's FORWARDED_ALLOW_IPS)",
        ),
    ] = None,
) -> None:
    """Serve the API with uvicorn (OpenAPI at /docs), until Ctrl-C."""
    if ctx.invoked_subcommand is not None:
        return
    owner_only_umask()  # what it writes is its own only (fleetbus.private_files)
    import uvicorn

    from fleetbus.api.app import create_app
    from fleetbus.broker.certificates import TlsFiles

    config = settings()
    files = TlsFiles.for_settings(config)
    if tls and not (files.cert.exists() and files.key.exists()):
        fail(
            f"--tls needs the server certificate {files.cert} and its key {files.key}: `fleetbus certs make`"
        )
    ep = endpoint()
    scheme = "https" if tls else "http"
    console.print(
        f"fleetbus API and console on {scheme}://{host}:{port}/ (API docs at /docs); "
        f"broker {ep.management_url}",
        soft_wrap=True,
    )
    if not tls:
        console.print(
            "[yellow]note:[/] plain HTTP: the login hands out broker passwords to clients on this machine "
            "only (--tls serves HTTPS)"
        )
    uvicorn.run(
        create_app(config, ep.amqp_url, ep.management_url, ep.public_url),
        host=host,
        port=port,
        log_level="info",
        forwarded_allow_ips=forwarded_allow_ips,
        timeout_graceful_shutdown=5,  # for requests under way (open console pages' streams end at once)
        ssl_certfile=str(files.cert) if tls else None,
        ssl_keyfile=str(files.key) if tls else None,
        ssl_context_factory=_profiled_context if tls else None,
    )


def _profiled_context(config: Any, default: Callable[[], ssl.SSLContext]) -> ssl.SSLContext:
    """uvicorn's own context (the certificate and key, its ALPN) held to the TLS profile: uvicorn
    has no setting for the lowest TLS version."""
    from fleetbus.broker.tls_profile import apply

    return apply(default())


@app.command("create-admin")
def create_admin(
    name: str,
    password_stdin: Annotated[
        bool, typer.Option("--password-stdin", help="read the password from standard input (scripts)")
    ] = False,
) -> None:
    """Create an admin on this server (the safe way to make the first one: no default password)."""
    from fleetbus.api.service import open_service
    from fleetbus.api.services.errors import ServiceRefusal

    if password_stdin:
        password = sys.stdin.readline().rstrip("\n")
    else:
        password = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    ep = endpoint()

    async def create() -> None:
        async with open_service(settings(), ep.amqp_url, ep.management_url) as service:
            await service.accounts.create(
                name, password, UserRole.ADMIN, None, by="fleetbus api create-admin"
            )

    try:
        asyncio.run(create())
    except ServiceRefusal as refusal:
        fail(refusal.detail)
    console.print(f"created admin [bold]{name}[/]; log in at POST /auth/token")


@app.command("openapi")
def openapi(out: Annotated[Path, typer.Argument(help="file to write")] = Path("openapi.json")) -> None:
    """Write the OpenAPI document (no broker needed)."""
    from fleetbus.api.app import create_app

    document = create_app(settings(), "amqp://localhost/", "http://localhost:15672/").openapi()
    out.write_text(json.dumps(document, indent=2) + "\n")
    console.print(f"wrote {out} ({len(document['paths'])} paths)")


@app.command("login")
def login(
    name: str,
    api: Annotated[
        str | None,
        typer.Option(help="the API's base URL (default: FLEETBUS_API_URL, else http://127.0.0.1:8000)"),
    ] = None,
    password_stdin: Annotated[bool, typer.Option("--password-stdin")] = False,
) -> None:
    """Log in; print the token and keep the broker URL in FLEETBUS_DATA_DIR/accounts/NAME.url."""
    import httpx

    api = api or settings().api_url
    password = (
        sys.stdin.readline().rstrip("\n") if password_stdin else typer.prompt("password", hide_input=True)
    )
    try:
        response = httpx.post(f"{api.rstrip('/')}/auth/token", data={"username": name, "password": password})
    except httpx.HTTPError as error:
        fail(f"cannot reach the API at {api}: {error}")
    if response.status_code != 200:
        fail(f"{response.status_code}: {response.json().get('detail', response.text)}")
    reply = response.json()
    console.print(f"logged in as {name} ({reply['user']['role']}) until {reply['expires_at']}")
    if reply.get("broker"):
        save_secret(settings().accounts_dir / f"{name}.url", reply["broker"]["amqp_url"])
        console.print(f"broker URL kept in {settings().accounts_dir / f'{name}.url'} (for `fleetbus tail`)")
    else:
        console.print(f"[yellow]no broker URL[/]: {reply.get('broker_withheld')}", soft_wrap=True)
    console.print(f"token: {reply['access_token']}", soft_wrap=True, highlight=False)


@app.command("end-sessions")
def end_sessions(
    name: str,
    by: Annotated[
        str | None, typer.Option(help="who ends them, for the record (default: your login)")
    ] = None,
) -> None:
    """End every login session of NAME in this server's store, as DELETE /users/NAME/sessions
    does: its console logins and API tokens are refused from their next request on."""
    who = actor(by)
    ended = with_services(lambda services: services.sessions.end(name, who))
    console.print(f"ended {ended} session(s) of {name}")
