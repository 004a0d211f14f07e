"""``fleetbus evaluate``: how well each behaviour does, computed by the database."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from fleetbus.cli.context import console, errors
from fleetbus.cli.services import with_recording
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.workers.recorder.queries import BEHAVIOUR


def evaluate(
    since: Annotated[str | None, typer.Option(help=f"recorded from this time: {TIME_FORMS}")] = None,
    until: Annotated[str | None, typer.Option(help="recorded before this time (the same forms)")] = None,
    robot: Annotated[str | None, typer.Option(help="only this robot")] = None,
    message_type: Annotated[str, typer.Option("--type", help="the type holding outcomes")] = BEHAVIOUR,
    name_field: Annotated[str, typer.Option(help="field naming the behaviour")] = "name",
    success_field: Annotated[str, typer.Option(help="field that is true on success")] = "success",
    duration_field: Annotated[str, typer.Option(help="field with the duration in seconds")] = "duration_s",
    plot: Annotated[Path | None, typer.Option(help="also write a PNG plot here")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="JSON lines instead of a table")] = False,
) -> None:
    """Per behaviour: successes, failures, success rate, mean and standard deviation of its duration."""
    start, end = parse_time(since, "--since"), parse_time(until, "--until")
    fields = (name_field, success_field, duration_field)
    stats = with_recording(
        lambda recording: recording.evaluate(start, end, robot_id=robot, type=message_type, fields=fields)
    )
    if as_json:
        for s in stats:
            typer.echo(json.dumps({**s.__dict__, "runs": s.runs, "success_rate": s.success_rate}))
    else:
        window = f"{since or 'the start'} to {until or 'now'}" + (f", robot {robot}" if robot else "")
        table = Table(title=f"{message_type} outcomes, {window}")
        for column in ("behaviour", "successes", "failures", "success rate", "mean s", "std dev s"):
            table.add_column(column, justify="left" if column == "behaviour" else "right")
        for s in stats:
            table.add_row(
                s.name,
                str(s.successes),
                str(s.failures),
                f"{100 * s.success_rate:.1f}%",
                f"{s.mean_duration:.3f}",
                f"{s.std_duration:.3f}",
            )
        console.print(table)
    if plot is not None:
        from fleetbus.cli.plots import plot_evaluation  # matplotlib loads in a second: only when asked

        say = errors if as_json else console  # keeps --json output clean
        if stats:
            plot_evaluation(stats, plot, f"{message_type} outcomes")
            say.print(f"wrote {plot}")
        else:
            say.print("nothing to plot: no outcomes in that window")
