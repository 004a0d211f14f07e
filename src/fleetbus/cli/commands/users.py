"""``fleetbus users add | remove | use-cases | list | check``: the account registry's users and
robots, each with a broker account confined to its own name, through the accounts service."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any
from urllib.parse import urlsplit

import pika.exceptions
import typer
from rich.table import Table
from rich.text import Text

from fleetbus.broker.accounts import can_login, save_secret
from fleetbus.broker.certificates import CertificateError, ClientFiles, TlsFiles, issue_client_certificate
from fleetbus.broker.fleet import NewRobot
from fleetbus.cli.accounts import with_accounts
from fleetbus.cli.context import actor, console, endpoint, fail, settings
from fleetbus.publishers.errors import CONNECTION_FAILED
from fleetbus.publishers.tls import split_tls, with_client_certificate
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import Settings

if TYPE_CHECKING:
    from fleetbus.api.services.account_check import Drift
    from fleetbus.api.services.accounts import Accounts
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.workers.store import Repositories
    from fleetbus.workers.store.users import User

app = typer.Typer(help="Broker accounts for users, robots and services.", no_args_is_help=True)


@app.command("add")
def add(
    name: str,
    role: Annotated[
        UserRole | None,
        typer.Option(
            help="its role (as the HTTP API's users have); default: robot, or with --rotate its own"
        ),
    ] = None,
    kind: Annotated[
        RobotKind | None,
        typer.Option(help="robot kind; decides its notifications (with --rotate: default its own)"),
    ] = None,
    rotate: Annotated[
        bool, typer.Option(help="give an existing account a new password, keeping its role and kind")
    ] = False,
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
    by: Annotated[str | None, typer.Option(help="who makes it, for the record (default: your login)")] = None,
) -> None:
    """Record a user or robot in the account registry (as `POST /users` does) and make its broker
    account with a random password (or, with --cert, none and a client certificate); its URL is
    printed once. Certificates fleetbus's CA signed earlier for NAME are revoked: the account logs
    in only with what this command hands out."""
    ep, config = endpoint(), settings()
    if cert and urlsplit(ep.public_url or ep.amqp_url).scheme != "amqps":
        fail("--cert needs a broker reached over TLS (amqps://): see docs/operations/tls.md")
    files = TlsFiles.for_settings(config)
    if cert and not files.ca_key.exists():
        fail(f"--cert signs the robot's certificate with the CA's key {files.ca_key}, which is missing")
    made = with_accounts(
        ep,
        lambda accounts, _repos, _api: accounts.provision(
            name, role, kind, actor(by), rotate=rotate, certificate=cert
        ),
    )
    if made.revoked:
        console.print(made.revoked, highlight=False)
    url = made.public_url
    client = _issue_certificate(config, name) if cert else None
    if client is not None:
        url = with_client_certificate(url, client.cert, client.key)
    if save:
        save_secret(config.accounts_dir / f"{name}.url", url)
    done = "gave a new password to" if rotate else "created"
    console.print(f"{done} {made.user.role.value} [bold]{name}[/]; its AMQP URL (shown once):")
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
    except (pika.exceptions.AMQPError, *CONNECTION_FAILED) as error:
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
    by: Annotated[
        str | None, typer.Option(help="who makes them, for the record (default: your login)")
    ] = None,
) -> None:
    """Make many robots at once (one broker import per 500), each recorded in the account registry
    with its exchanges, inbox, permissions and shard, as `users add` makes one; their URLs go to
    the --urls file, never to the screen."""
    ep = endpoint()
    try:
        robots = read_robots(names.read_text(), kind)
    except (OSError, ValueError) as error:
        fail(f"{names}: {error}")
    if urls.exists():
        fail(f"{urls} exists; give a new file for the URLs")
    made = with_accounts(
        ep, lambda accounts, _repos, _api: accounts.provision_robots(robots, actor(by), rotate=rotate)
    )
    save_secret(urls, "\n".join(f"{m.user.name} {m.public_url}" for m in made))
    console.print(f"created {len(made):,} robots; their URLs are in {urls}", highlight=False)


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
    """Remove a user or robot (as `DELETE /users/NAME` does): from the registry, its broker
    account, and the hazard gate's team (its exchange and inbox stay, with whatever they hold); a
    warden removed no longer holds the gate. Refused while it is mounted or checked in. Its client
    certificates are revoked."""
    ep = endpoint()
    removed = with_accounts(ep, lambda accounts, _repos, _api: accounts.remove(name, actor(by)))
    (settings().accounts_dir / f"{name}.url").unlink(missing_ok=True)
    console.print(f"removed {name}" + (" and took it out of the team" if removed.left_team else ""))
    if removed.revoked:
        console.print(removed.revoked, highlight=False)


@app.command("use-cases")
def use_cases(
    name: str,
    allow: Annotated[
        str | None,
        typer.Option(help='the use cases NAME may create missions of, comma-separated ("": none)'),
    ] = None,
    every: Annotated[
        bool, typer.Option("--all", help="every use case, those added later too (the default)")
    ] = False,
    by: Annotated[
        str | None, typer.Option(help="who changes them, for the record (default: your login)")
    ] = None,
) -> None:
    """Show or set the use cases NAME may create missions of (as `PUT /users/NAME/use-cases`); a
    mission of another is refused, through the HTTP API, the console and `fleetbus missions create`.
    An account none were set for may use every use case."""
    if allow is not None and every:
        fail("give --allow or --all, not both", 2)
    ep = endpoint()
    if allow is None and not every:
        user = with_accounts(ep, lambda accounts, _repos, _api: accounts.get(name))
    else:
        wanted = None if every else allow.split(",") if allow else []
        user = with_accounts(
            ep, lambda accounts, _repos, _api: accounts.set_use_cases(name, wanted, actor(by))
        )
    allowed = "every use case" if user.use_cases is None else ", ".join(user.use_cases) or "none"
    console.print(f"{name} may create missions of: {allowed}", highlight=False)


@app.command("list")
def list_users(as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False) -> None:
    """The account registry's users and robots (the one record of each), how each logs in to the
    broker (a password, or a client certificate only), and what of it drifted from the registry, as
    `users check` finds it. Drift about no user of the registry (a broker account made outside it,
    a site's account) is listed after them."""
    from fleetbus.api.services.account_check import account_check_for

    ep, config = endpoint(), settings()

    async def run(
        accounts: Accounts, repos: Repositories, api: ManagementAPI
    ) -> tuple[list[User], dict[str, dict[str, Any]], list[Drift]]:
        checker = account_check_for(accounts, repos, api, ep.amqp_url, config.ingest_shards)
        drift = await checker.drift()
        broker = {user["name"]: user for user in await asyncio.to_thread(api.list_users)}
        return await repos.users.users(), broker, drift

    users, broker, drift = with_accounts(ep, run)
    listed = [
        {
            "name": user.name,
            "role": user.role.value,
            "kind": user.kind,
            "login": _login(broker.get(user.name)),
            "drift": [d.as_dict() for d in drift if d.name == user.name],
        }
        for user in sorted(users, key=lambda u: u.name)
    ]
    names = {user.name for user in users}
    other = [d.as_dict() for d in drift if d.name not in names]
    if as_json:
        console.print_json(json.dumps({"users": listed, "other_drift": other}))
        return
    table = Table("user", "role", "kind", "login", "drift")
    for row in listed:
        problems = "; ".join(d["problem"] for d in row["drift"])
        table.add_row(row["name"], row["role"], row["kind"] or "", row["login"], Text(problems, "yellow"))
    console.print(table)
    for d in other:
        console.print(Text.assemble((d["kind"], "yellow"), f" {d['name']}: {d['problem']}"))
    if drift:
        console.print("`fleetbus users check --repair` makes the broker and the sites the registry's again")


def _login(account: dict[str, Any] | None) -> str:
    """How a broker account logs in: a password, or (none set) a client certificate only."""
    if account is None:
        return "none"
    return "password" if account.get("password_hash") else "certificate"


@app.command("check")
def check(
    repair: Annotated[bool, typer.Option("--repair", help="repair what differs")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="one JSON document")] = False,
    by: Annotated[str | None, typer.Option(help="who repairs, for the record (default: your login)")] = None,
) -> None:
    """Compare the account registry with what derives from it (the broker's accounts, permissions,
    topic permissions and shard bindings, the team, the sites' accounts at central), as the
    console's dashboard and `GET /registry/drift` do; with --repair, make those the registry's again
    (`POST /registry/repair`). Exits 1 when something differs (after --repair: still differs)."""
    from fleetbus.api.services.account_check import account_check_for

    ep, config = endpoint(), settings()

    async def run(
        accounts: Accounts, repos: Repositories, api: ManagementAPI
    ) -> tuple[list[Drift], list[Drift]]:
        checker = account_check_for(accounts, repos, api, ep.amqp_url, config.ingest_shards)
        repaired = await checker.repair(actor(by)) if repair else []
        return repaired, await checker.drift()

    repaired, left = with_accounts(ep, run)
    if as_json:
        document = {"repaired": [d.as_dict() for d in repaired], "drift": [d.as_dict() for d in left]}
        console.print_json(json.dumps(document))
    else:
        for drift in repaired:
            console.print(f"repaired {drift.kind} {drift.name}: {drift.problem}", highlight=False)
        for drift in left:
            console.print(f"[yellow]{drift.kind}[/] {drift.name}: {drift.problem} (repair: {drift.repair})")
        if not left:
            console.print("the broker, the team and the sites agree with the account registry")
    if left:
        raise typer.Exit(1)
