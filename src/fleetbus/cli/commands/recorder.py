"""``fleetbus recorder``: record every message on the bus on its own, and see what is recorded."""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.broker.accounts import RECORDER_USER
from fleetbus.cli.context import clock, console, fail, service_account, settings
from fleetbus.cli.services import with_recording
from fleetbus.limits import parse_retention, policy_for
from fleetbus.private_files import owner_only_umask
from fleetbus.workers.recorder.capture import KNOWN_TYPES
from fleetbus.workers.recorder.launch import Launch, exec_recorder
from fleetbus.workers.recorder.process import die_with_parent

app = typer.Typer(help="The recorder of every message on the bus.", no_args_is_help=True)


@app.command()
def run(
    include: Annotated[
        list[str] | None, typer.Option(help="record only routing keys matching (topic syntax, repeatable)")
    ] = None,
    exclude: Annotated[list[str] | None, typer.Option(help="never record routing keys matching")] = None,
    keep: Annotated[
        list[str] | None,
        typer.Option(help="retention, TYPE=7d | 500MB | 100000 (records); * for any other type; repeatable"),
    ] = None,
    sample_every: Annotated[float, typer.Option(help="seconds between database size samples")] = 60.0,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Record every message on the bus until SIGTERM or Ctrl-C (`fleetbus worker` does it too).

    Runs as the `fleetbus-recorder` account only, which may read its one queue: `fleetbus setup`
    makes the account and the queue."""
    die_with_parent()  # when `fleetbus worker` started it (the death signal outlives the exec)
    owner_only_umask()  # what it writes is its own only (fleetbus.private_files)
    try:
        launch = Launch.resolve(
            settings(),
            url="",
            include=include or [],
            exclude=exclude or [],
            keep=keep or [],
            sample_interval=sample_every,
            verbose=verbose,
        )
    except ValueError as error:
        fail(str(error), code=2)
    # the same process goes on recording without the command line's imports
    exec_recorder(replace(launch, url=service_account(RECORDER_USER)))


@app.command()
def types(
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """Every recorded type: known or not, how many records and bytes, from when to when, its indexes."""

    rows = [(view.summary, view.field_indexes) for view in with_recording(lambda r: r.type_views())]
    retention = parse_retention(settings().recorder_keep)
    if as_json:
        for summary, indexes in rows:
            view = {**summary.__dict__, "known": summary.type in KNOWN_TYPES, "field_indexes": indexes}
            view["first"] = summary.first.isoformat() if summary.first else None
            view["last"] = summary.last.isoformat() if summary.last else None
            typer.echo(json.dumps(view))
        return
    table = Table(title=f"{len(rows)} recorded types")
    for column in ("type", "known", "records", "MB"):
        table.add_column(column, no_wrap=True, justify="left" if column in ("type", "known") else "right")
    for column in ("first (UTC)", "last (UTC)", "kept", "field indexes"):
        table.add_column(column)
    for summary, indexes in rows:
        policy = policy_for(retention, summary.type)
        table.add_row(
            summary.type,
            "yes" if summary.type in KNOWN_TYPES else "no",
            str(summary.records),
            f"{summary.bytes / 1e6:.2f}",
            clock(summary.first)[:19] if summary.first else "",
            clock(summary.last)[:19] if summary.last else "",
            policy.describe() if policy else "everything",
            "; ".join(", ".join(paths) for paths in indexes),
        )
    console.print(table)
