"""The ``fleetbus`` console script: one Typer app, one module per command group."""

from __future__ import annotations

import typer

from fleetbus.commands import (
    api,
    beacons,
    broker,
    demo,
    dlq,
    events,
    hazards,
    maps,
    outbox,
    schemas_export,
    tail,
    users,
    worker,
)

app = typer.Typer(
    name="fleetbus",
    help="Event backbone and database server for a team of robots.",
    no_args_is_help=True,
    pretty_exceptions_show_locals=False,
)
app.add_typer(broker.app, name="broker")
app.add_typer(users.app, name="users")
app.add_typer(beacons.app, name="beacons")
app.add_typer(maps.app, name="map")
app.add_typer(api.app, name="api")
app.command("worker")(worker.worker)
app.command("publish")(events.publish)
app.command("query")(events.query)
app.command("dlq")(dlq.dlq)
app.command("outbox")(outbox.outbox)
app.command("hazards")(hazards.hazards)
app.command("demo")(demo.demo)
app.command("schemas")(schemas_export.export_schemas)
app.command("tail")(tail.tail)

if __name__ == "__main__":
    app()
