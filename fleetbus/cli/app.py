"""The ``fleetbus`` console script: one Typer app, one module per command group."""

from __future__ import annotations

import typer

from fleetbus.cli.commands import (
    api,
    beacons,
    broker,
    demo,
    dlq,
    evaluate,
    events,
    hazards,
    maps,
    outbox,
    recorder,
    replay,
    schemas_export,
    setup,
    shards,
    stats,
    tail,
    team,
    timeline,
    trace,
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
app.add_typer(recorder.app, name="recorder")
app.add_typer(api.app, name="api")
app.add_typer(shards.app, name="shards")
app.add_typer(team.app, name="team")
app.command("worker")(worker.worker)
app.command("setup")(setup.setup)
app.command("publish")(events.publish)
app.command("query")(events.query)
app.command("dlq")(dlq.dlq)
app.command("outbox")(outbox.outbox)
app.command("hazards")(hazards.hazards)
app.command("demo")(demo.demo)
app.command("schemas")(schemas_export.export_schemas)
app.command("tail")(tail.tail)
app.command("timeline")(timeline.timeline)
app.command("trace")(trace.trace)
app.command("evaluate")(evaluate.evaluate)
app.command("replay")(replay.replay)
app.command("stats")(stats.stats)

if __name__ == "__main__":
    app()
