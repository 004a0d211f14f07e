"""``fleetbus certs make | show``: the CA and the server certificate the broker and the API use."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fleetbus.broker.certificates import CertificateError, TlsFiles, describe, make_certificates
from fleetbus.cli.context import console, fail, settings

app = typer.Typer(
    help="TLS: a CA and a server certificate for the broker and the API, or your own files.",
    no_args_is_help=True,
)

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
