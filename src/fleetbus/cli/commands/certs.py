"""``fleetbus certs make | show | client | revoke``: the CA and the server certificate the broker and
the API use, and client certificates robots log in with."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.broker.certificates import (
    CertificateError,
    ClientFiles,
    TlsFiles,
    describe,
    issue_client_certificate,
    make_certificates,
)
from fleetbus.broker.revocation import (
    ensure_crl,
    issued_certificates,
    read_crl,
    revoke,
    revoke_certificates_of,
)
from fleetbus.cli.context import console, fail, settings
from fleetbus.schemas.identity import validate_name

app = typer.Typer(
    help="TLS: a CA and a server certificate for the broker and the API, or your own files.",
    no_args_is_help=True,
)

#: A client certificate this close to its expiry is shown as expiring: sign the robot a new one.
EXPIRING = timedelta(days=30)

DirOption = Annotated[
    Path | None, typer.Option("--dir", help="folder of the files (default: FLEETBUS_TLS_DIR)")
]


def _files(folder: Path | None) -> TlsFiles:
    return TlsFiles.in_folder(folder.resolve()) if folder else TlsFiles.for_settings(settings())


@app.command("make")
def make(
    folder: DirOption = None,
    host: Annotated[
        list[str] | None,
        typer.Option("--host", help="a DNS name or IP address clients use to reach this server (repeatable)"),
    ] = None,
) -> None:
    """Make a CA (an existing one is kept) and a server certificate it signs, for localhost,
    127.0.0.1 and every --host. Restart the broker (`fleetbus broker down` and `up`) to use a new one."""
    files = _files(folder)
    config = settings()
    if folder is None and (config.tls_ca or config.tls_cert or config.tls_key):
        fail("FLEETBUS_TLS_CA, _CERT or _KEY name your own files: make certificates with --dir")
    try:
        made_ca = make_certificates(files, host or [])
        ensure_crl(files)
    except CertificateError as error:
        fail(str(error))
    done = "made" if made_ca else "kept"
    console.print(f"{done} the CA {files.ca} (its key: {files.ca_key}, 0600)", soft_wrap=True)
    console.print(f"made the server certificate {files.cert} (its key: {files.key}, 0600)", soft_wrap=True)
    console.print(
        f"robots verify the broker with {files.ca}: copy it to them (or GET /ca.pem from the API)",
        soft_wrap=True,
    )


@app.command("show")
def show(folder: DirOption = None) -> None:
    """The CA and the server certificate: paths, subjects, names and expiry."""
    files = _files(folder)
    for what, path in (("CA", files.ca), ("server certificate", files.cert)):
        if not path.exists():
            console.print(f"{what}: {path} is missing (`fleetbus certs make`)", soft_wrap=True)
            continue
        try:
            info = describe(path)
        except CertificateError as error:
            fail(str(error))
        console.print(f"{what}: {info.path}", soft_wrap=True)
        console.print(f"  subject: {info.subject}; issuer: {info.issuer}", soft_wrap=True)
        if info.names:
            console.print(f"  names: {', '.join(info.names)}", soft_wrap=True)
        console.print(f"  expires: {info.not_after.isoformat()}", soft_wrap=True)
    console.print(f"server key: {files.key}{'' if files.key.exists() else ' (missing)'}", soft_wrap=True)
    _show_revocation(files)


def _show_revocation(files: TlsFiles) -> None:
    """The revocation list, and the client certificates the CA signed with their state."""
    if not files.ca.exists():
        return
    try:
        crl = read_crl(files)
        issued = issued_certificates(files)
    except CertificateError as error:
        fail(str(error))
    if crl is None:
        console.print("revocation list: none (client certificates cannot be revoked)", soft_wrap=True)
    else:
        until = crl.next_update.isoformat() if crl.next_update else "?"
        console.print(
            f"revocation list: {crl.path} ({len(crl.revoked)} revoked; valid until {until})", soft_wrap=True
        )
    if not issued:
        return
    table = Table(title=f"{len(issued)} client certificates signed by the CA")
    for column in ("account", "serial", "expires", "state"):
        table.add_column(column)
    now = datetime.now(timezone.utc)
    for cert in issued:
        revoked = crl.revoked.get(cert.serial) if crl else None
        if revoked is not None:
            state = f"[red]revoked[/] {revoked:%Y-%m-%d %H:%M}"
        elif cert.not_after < now:
            state = "expired"
        elif cert.not_after < now + EXPIRING:
            state = f"[yellow]expires in {(cert.not_after - now).days} days[/]"
        else:
            state = "[green]valid[/]"
        table.add_row(cert.name, f"{cert.serial:x}", f"{cert.not_after:%Y-%m-%d}", state)
    console.print(table)


@app.command("client")
def client(
    name: str,
    folder: DirOption = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", help="folder to write NAME.pem and NAME.key in (default: clients/ beside the CA)"
        ),
    ] = None,
) -> None:
    """Sign a client certificate for the account NAME (CN=NAME) with fleetbus's CA: a broker that
    takes the login from the certificate (EXTERNAL) logs its holder in as NAME. `fleetbus users add
    NAME --cert` makes the account without a password and this certificate at once."""
    try:
        validate_name(name)
    except ValueError as error:
        fail(str(error))
    files = _files(folder)
    client_files = ClientFiles.in_folder(out.resolve() if out else files.clients, name)
    try:
        issue_client_certificate(files, client_files, name)
    except CertificateError as error:
        fail(str(error))
    console.print(f"made the client certificate {client_files.cert} (CN={name})", soft_wrap=True)
    console.print(f"its key: {client_files.key} (0600): give both to {name} only", soft_wrap=True)
    console.print(
        f"its URL logs in with them: amqps://{name}@<broker>:<port>/?cacertfile={files.ca}"
        f"&certfile={client_files.cert}&keyfile={client_files.key}&auth_mechanism=external",
        soft_wrap=True,
        highlight=False,
    )


@app.command("revoke")
def revoke_command(
    name: Annotated[str, typer.Argument(help="the account whose certificates are revoked")],
    serial: Annotated[
        str | None,
        typer.Option("--serial", help="only this certificate (hexadecimal, as `certs show` lists)"),
    ] = None,
    folder: DirOption = None,
) -> None:
    """Revoke the client certificates fleetbus's CA signed for NAME (or one of them): the broker
    refuses them at their next connection, without a restart. Connections open now stay open:
    `fleetbus users remove NAME` (or close them in the management UI) to cut them off too."""
    files = _files(folder)
    try:
        if serial is None:
            done = revoke_certificates_of(files, name)
        else:
            mine = {cert.serial for cert in issued_certificates(files, name)}
            try:
                wanted = int(serial, 16)
            except ValueError:
                fail(f"--serial {serial!r} is not a hexadecimal serial number")
            if wanted not in mine:
                fail(f"the CA signed no certificate {serial} for {name} (`fleetbus certs show` lists them)")
            done = revoke(files, [wanted])
    except CertificateError as error:
        fail(str(error))
    if not done:
        console.print(f"nothing to revoke: {name} has no unrevoked certificate of this CA", soft_wrap=True)
        return
    serials = ", ".join(f"{number:x}" for number in done)
    console.print(f"revoked {len(done)} certificate(s) of {name} (serial {serials})", soft_wrap=True)
