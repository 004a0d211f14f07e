"""``fleetbus users add | remove | list``: broker accounts confined to their own names."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Annotated
from urllib.parse import urlsplit

import pika.exceptions
import typer
from rich.table import Table

from fleetbus.broker.accounts import (
    AccountExists,
    Role,
    as_public,
    can_login,
    delete_account,
    provision_account,
    save_secret,
)
from fleetbus.broker.certificates import CertificateError, ClientFiles, TlsFiles, issue_client_certificate
from fleetbus.broker.fleet import NewRobot, RobotsExist, provision_robots
from fleetbus.broker.revocation import cannot_revoke, revoke_certificates_of, revoked_summary
from fleetbus.broker.team_changes import HazardServiceNotTold
from fleetbus.broker.tls import split_tls, with_client_certificate
from fleetbus.cli.context import actor, admin_api, console, endpoint, fail, settings
from fleetbus.cli.registry import register_robot, register_robots
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import Settings
from fleetbus.workers.store import run_with_repositories
from fleetbus.workers.team import leave_team

app = typer.Typer(help="Broker accounts for users, robots and services.", no_args_is_help=True)


@app.command("add")
def add(
    name: str,
    role: Annotated[Role, typer.Option(help="what the account is for")] = Role.ROBOT,
    kind: Annotated[RobotKind | None, typer.Option(help="robot kind; decides its notifications")] = None,
    rotate: Annotated[bool, typer.Option(help="give an existing account a new password")] = False,
    save: Annotated[
        bool, typer.Option(help="keep the URL in FLEETBUS_DATA_DIR/accounts for `publish`")
    ] = True,
    cert: Annotated[
        bool,
        typer.Option(
            "--cert",
            help="no password: the account logs in with a client certificate (CN=NAME) made now, "
            "signed by fleetbus's CA (docs/operations/tls.md)",
        ),
    ] = False,
) -> None:
    """Create an account with a random password (or, with --cert, none and a client certificate);
    its URL is printed once. Certificates fleetbus's CA signed earlier for NAME are revoked: the
    account logs in only with what this command hands out."""
    ep, config = endpoint(), settings()
    if cert and urlsplit(ep.public_url or ep.amqp_url).scheme != "amqps":
        fail("--cert needs a broker reached over TLS (amqps://): see docs/operations/tls.md")
    files = TlsFiles.for_settings(config)
    if cert and not files.ca_key.exists():
        fail(f"--cert signs the robot's certificate with the CA's key {files.ca_key}, which is missing")
    if problem := cannot_revoke(files, name):
        fail(problem)
    with admin_api(ep) as api:
        try:
            account = asyncio.run(
                provision_account(
                    ep.amqp_url,
                    api,
                    name,
                    role,
                    kind,
                    rotate=rotate,
                    shards=config.ingest_shards,
                    cluster=config.cluster,
                    password_login=not cert,
                )
            )
        except (AccountExists, ValueError) as error:
            fail(str(error))
    if role is Role.ROBOT:
        register_robot(config, name, kind)
    _revoke(files, name)
    url = as_public(account.amqp_url, ep.public_url)
    client = _issue_certificate(config, name) if cert else None
    if client is not None:
        url = with_client_certificate(url, client.cert, client.key)
    if save:
        save_secret(config.accounts_dir / f"{name}.url", url)
    console.print(f"created {role.value} [bold]{name}[/]; its AMQP URL (shown once):")
    console.print(url, soft_wrap=True, highlight=False)
    if client is not None:
        _say_certificate(client, url)
    _, tls = split_tls(url)
    if tls is not None and tls.cacertfile:
        console.print(
            f"it verifies the broker with the CA {tls.cacertfile} (give the robot a copy there, or "
            "fetch it from the API's GET /ca.pem)",
            soft_wrap=True,
            highlight=False,
        )


def _revoke(files: TlsFiles, name: str) -> None:
    """Revoke every certificate of ``name`` the CA signed; say so when there were any."""
    try:
        revoked = revoke_certificates_of(files, name)
    except CertificateError as error:
        fail(f"could not revoke the certificates of {name}: {error}")
    if revoked:
        console.print(revoked_summary(name, revoked))


def _issue_certificate(config: Settings, name: str) -> ClientFiles:
    """``name``'s client certificate (CN=name), signed by fleetbus's CA."""
    files = TlsFiles.for_settings(config)
    client = ClientFiles.in_folder(files.clients, name)
    try:
        issue_client_certificate(files, client, name)
    except CertificateError as error:
        fail(f"made the account {name} (it has no password), but not its certificate: {error}")
    return client


def _say_certificate(client: ClientFiles, url: str) -> None:
    console.print(
        f"it has no password: it logs in with its client certificate {client.cert} and key "
        f"{client.key} (0600; copy both to the robot only)",
        soft_wrap=True,
        highlight=False,
    )
    try:
        accepted = can_login(url)
    except pika.exceptions.AMQPError as error:
        console.print(f"[yellow]could not try the certificate's login: {error}[/]", soft_wrap=True)
        return
    if not accepted:
        console.print(
            "[yellow]the broker refuses the certificate's login: it needs the EXTERNAL mechanism "
            "(the private node gets it at its next start: `fleetbus broker down`, then `up`)[/]",
            soft_wrap=True,
            highlight=False,
        )


@app.command("add-many")
def add_many(
    names: Annotated[
        Path,
        typer.Argument(
            help="a file of robots, one a line: NAME, or NAME KIND (explorer, warden, guide); "
            "blank lines and lines starting with # are skipped"
        ),
    ],
    urls: Annotated[
        Path,
        typer.Option(help="where to write each robot's AMQP URL, one `NAME URL` a line (made mode 0600)"),
    ],
    kind: Annotated[RobotKind | None, typer.Option(help="the kind of robots whose line names none")] = None,
    rotate: Annotated[bool, typer.Option(help="give existing accounts new passwords")] = False,
) -> None:
    """Make many robots' accounts at once (one broker import per 500), each with its exchanges,
    inbox, permissions and shard, as `users add` makes one; their URLs go to the --urls file, never
    to the screen."""
    ep, config = endpoint(), settings()
    try:
        robots = read_robots(names.read_text(), kind)
    except (OSError, ValueError) as error:
        fail(f"{names}: {error}")
    if urls.exists():
        fail(f"{urls} exists; give a new file for the URLs")
    with admin_api(ep) as api:
        try:
            accounts = asyncio.run(
                provision_robots(
                    ep.amqp_url,
                    api,
                    robots,
                    rotate=rotate,
                    shards=config.ingest_shards,
                    cluster=config.cluster,
                )
            )
        except (RobotsExist, ValueError) as error:
            fail(str(error))
    register_robots(config, [(robot.name, robot.kind) for robot in robots])
    save_secret(urls, "\n".join(f"{a.name} {as_public(a.amqp_url, ep.public_url)}" for a in accounts))
    console.print(f"created {len(accounts):,} robots; their URLs are in {urls}", highlight=False)


def read_robots(text: str, kind: RobotKind | None) -> list[NewRobot]:
    """The robots of a names file; raises ValueError naming the line that does not parse."""
    robots = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) > 2:
            raise ValueError(f"line {number}: NAME or NAME KIND, not {line.strip()!r}")
        try:
            robots.append(NewRobot(validate_name(words[0]), RobotKind(words[1]) if len(words) == 2 else kind))
        except ValueError as error:
            raise ValueError(f"line {number}: {error}") from None
    if not robots:
        raise ValueError("no robot named")
    return robots


@app.command("remove")
def remove(
    name: str,
    by: Annotated[
        str | None, typer.Option(help="who removes it, for the record (default: your login)")
    ] = None,
) -> None:
    """Delete an account and take it out of the hazard gate's team (its exchange and inbox stay,
    with whatever they hold); a warden removed no longer holds the gate. Its client certificates
    are revoked."""
    ep, files = endpoint(), TlsFiles.for_settings(settings())
    if problem := cannot_revoke(files, name):
        fail(problem)
    with admin_api(ep) as api:
        try:
            delete_account(ep.amqp_url, api, name)
        except ValueError as error:
            fail(str(error))
    (settings().accounts_dir / f"{name}.url").unlink(missing_ok=True)
    who = actor(by)
    try:
        left = run_with_repositories(
            settings(), lambda repos: leave_team(repos.hazards, ep.amqp_url, name, who)
        )
    except HazardServiceNotTold as error:
        fail(f"removed {name} and took it out of the team, but {error}")
    console.print(f"removed {name}" + (" and took it out of the team" if left else ""))
    _revoke(files, name)  # a later account of that name must not inherit them


@app.command("list")
def list_users() -> None:
    """The broker's accounts, their tags and how they log in (a password, or a client certificate
    only)."""
    ep = endpoint()
    with admin_api(ep) as api:
        users = api.list_users()
    table = Table("user", "tags", "login")
    for user in sorted(users, key=lambda u: u["name"]):
        tags = user.get("tags") or []
        login = "password" if user.get("password_hash") else "certificate"
        table.add_row(user["name"], ",".join(tags) if isinstance(tags, list) else str(tags), login)
    console.print(table)
