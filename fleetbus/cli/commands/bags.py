"""``fleetbus import``: a ROS bag into the recording; ``fleetbus export --mcap``: the recording
into an MCAP file for Foxglove."""

from __future__ import annotations

import importlib.util
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from fleetbus.cli.context import (
    console,
    errors,
    fail,
    recording_stream,
    settings,
    with_recording,
)
from fleetbus.cli.times import TIME_FORMS, parse_time
from fleetbus.workers.store.recordings import RecordedMessage, RecordingError

PHASES = {"check": "reading the bag", "store": "storing"}


def import_bag(
    path: Annotated[
        Path, typer.Argument(help="a ROS 1 .bag file, or a ROS 2 bag (directory, .db3 or .mcap)")
    ],
    robot: Annotated[str, typer.Option(help="the robot the bag's messages are recorded as")],
    as_json: Annotated[bool, typer.Option("--json", help="print the report as JSON")] = False,
) -> None:
    """Import every message of a ROS bag into the recording, as the robot's, with the bag's times.

    The bag is read to the end before anything is stored, so a truncated or corrupt bag stores
    nothing; importing the same bag again stores nothing twice."""
    from fleetbus.schemas.identity import validate_name
    from fleetbus.workers.recorder.bag_import import import_bag as run_import
    from fleetbus.workers.recorder.bags import BagError

    try:
        validate_name(robot)
    except ValueError as error:
        fail(str(error), code=2)
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=errors, transient=True) as progress:
        tasks: dict[str, int] = {}

        def advance(phase: str, done: int, total: int) -> None:
            if phase not in tasks:
                tasks[phase] = progress.add_task(PHASES[phase], total=total or None)
            progress.update(tasks[phase], completed=done)

        try:
            report = with_recording(
                lambda store: run_import(store, path, robot, settings().max_message_bytes, advance)
            )
        except BagError as error:
            fail(f"{error}; nothing was imported")
    if as_json:
        typer.echo(json.dumps({**report.__dict__, "already": report.already}))
        return
    if report.stored == 0 and report.already:
        text = f"nothing new: all {report.already} messages of {path} were in the recording already"
        text += " (imported before)"
    else:
        text = f"imported {report.stored} messages of {path} as {robot}'s"
    if report.already and report.stored:
        text += f"; {report.already} were in the recording already (imported before)"
    if report.trimmed:
        text += f"; {report.trimmed} had arrays over the size limit described, not kept"
    console.print(text)


def export(
    mcap: Annotated[Path, typer.Option("--mcap", help="the MCAP file to write")],
    robots: Annotated[list[str] | None, typer.Option("--robot", help="only this robot (repeatable)")] = None,
    message_types: Annotated[
        list[str] | None,
        typer.Option(
            "--type", help="only this type, e.g. hazard or ros (repeatable; default: all but dead letters)"
        ),
    ] = None,
    since: Annotated[
        str | None,
        typer.Option(help=f"recorded from this time (default: the start): {TIME_FORMS}"),
    ] = None,
    until: Annotated[
        str | None, typer.Option(help="recorded before this time (default: now; the same forms)")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="replace the file if it exists")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="print the report as JSON")] = False,
) -> None:
    """Write the recorded messages of a window to an MCAP file: each fleetbus type on a JSON
    channel with its schema, the maps, poses and hazards also as Foxglove messages, imported
    ROS messages on their topics. Streamed: the window's length does not matter."""
    from fleetbus.workers.recorder.mcap_export import export_mcap
    from fleetbus.workers.recorder.queries import recorded_between

    if importlib.util.find_spec("mcap") is None:
        fail("writing MCAP files needs the mcap package: pip install 'fleetbus[ros]'")
    if mcap.exists() and not force:
        fail(f"{mcap} exists; add --force to replace it", code=2)
    start, end = parse_time(since, "--since"), parse_time(until, "--until")
    wanted = set(robots or [])
    partial = mcap.with_name(mcap.name + ".partial")
    columns = (TextColumn("exporting: {task.completed:,.0f} messages"), TimeElapsedColumn())
    try:
        with (
            recording_stream(
                lambda store: recorded_between(
                    store,
                    start,
                    end,
                    types=message_types or [],
                    robot_id=next(iter(wanted)) if len(wanted) == 1 else None,
                )
            ) as records,
            Progress(*columns, console=errors, transient=True) as progress,
            partial.open("wb") as stream,
        ):
            task = progress.add_task("export", total=None)
            chosen: Iterator[RecordedMessage] = (r for r in records if not wanted or r.robot_id in wanted)
            report = export_mcap(chosen, stream, on_each=lambda record: progress.advance(task))
        os.replace(partial, mcap)
    except RecordingError as error:
        partial.unlink(missing_ok=True)
        fail(str(error), code=2)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    if as_json:
        typer.echo(json.dumps({"file": str(mcap), **report.__dict__}))
        return
    console.print(
        f"wrote {report.messages} messages (and {report.views} Foxglove views) on "
        f"{len(report.channels)} topics to {mcap}"
    )
