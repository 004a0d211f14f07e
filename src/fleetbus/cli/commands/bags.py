"""``fleetbus import``: a ROS bag into the recording; ``fleetbus export --mcap``: the recording
into an MCAP file for Foxglove."""

from __future__ import annotations

import importlib.util
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from fleetbus.cli.context import console, errors, fail, settings
from fleetbus.cli.services import fail_refused, recording_stream, with_recording
from fleetbus.cli.times import TIME_FORMS, parse_time_ns

if TYPE_CHECKING:
    from fleetbus.api.services.recording import RecordedMessage

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
                lambda recording: recording.import_bag(
                    path, robot, settings().max_message_bytes, advance, settings().ros_blob_max_bytes
                )
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
    mcap: Annotated[Path | None, typer.Option("--mcap", help="the MCAP file to write")] = None,
    bag: Annotated[Path | None, typer.Option("--bag", help="a ROS 1 bag to write (ROS messages)")] = None,
    robots: Annotated[list[str] | None, typer.Option("--robot", help="only this robot (repeatable)")] = None,
    message_types: Annotated[
        list[str] | None,
        typer.Option(
            "--type", help="only this type, e.g. hazard or ros (repeatable; default: all but dead letters)"
        ),
    ] = None,
    topics: Annotated[
        list[str] | None,
        typer.Option("--topic", help="only ROS messages on this topic; `*` and `?` match (repeatable)"),
    ] = None,
    since: Annotated[
        str | None,
        typer.Option(
            help=f"recorded from this time (default: the start): {TIME_FORMS}; or nanoseconds since 1970"
        ),
    ] = None,
    until: Annotated[
        str | None, typer.Option(help="recorded before this time (default: now; the same forms)")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="replace the file if it exists")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="print the report as JSON")] = False,
) -> None:
    """Write the recorded messages of a window to an MCAP file (or a ROS 1 bag): ROS messages on
    `/<robot><topic>` in their native encoding with their definitions; each fleetbus type on a JSON
    channel with its schema, the maps, poses and hazards also as Foxglove messages. Streamed: the
    window's length does not matter."""
    from fleetbus.api.services.errors import ServiceRefusal
    from fleetbus.workers.recorder.export_selection import Selection

    if (mcap is None) == (bag is None):
        fail("name one file to write: --mcap FILE or --bag FILE", code=2)
    target = mcap or bag
    assert target is not None
    needs = "mcap" if mcap else "rosbags"
    if importlib.util.find_spec(needs) is None:
        fail(f"writing this file needs the {needs} package: pip install 'fleetbus[ros]'")
    if target.exists() and not force:
        fail(f"{target} exists; add --force to replace it", code=2)
    try:
        selection = Selection(
            tuple(robots or ()),
            tuple(message_types or ()),
            tuple(topics or ()),
            parse_time_ns(since, "--since"),
            parse_time_ns(until, "--until"),
        )
    except ValueError as error:  # the recording's refusal of the window
        fail(str(error), code=2)
    schemas = with_recording(lambda recording: recording.ros_schemas(selection))
    partial = target.with_name(target.name + ".partial")
    columns = (TextColumn("exporting: {task.completed:,.0f} messages"), TimeElapsedColumn())
    try:
        with (
            recording_stream(lambda recording: recording.selected(selection)) as records,
            Progress(*columns, console=errors, transient=True) as progress,
        ):
            task = progress.add_task("export", total=None)
            advance = lambda: progress.advance(task)  # noqa: E731
            report = write_file(mcap, bag, partial, records, schemas, selection, advance)
        if report.messages == 0:
            partial.unlink(missing_ok=True)
            fail(f"nothing to export: no recorded message matches ({describe(selection)}); no file written")
        os.replace(partial, target)
    except ServiceRefusal as refusal:
        partial.unlink(missing_ok=True)
        fail_refused(refusal)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    if as_json:
        typer.echo(json.dumps({"file": str(target), **report.__dict__}))
        return
    text = f"wrote {report.messages} messages"
    text += f" (and {report.views} Foxglove views)" if mcap else ""
    console.print(f"{text} on {len(report.channels)} topics to {target}")
    for why, count in report.not_encoded.items():
        errors.print(f"[yellow]left out {count} ROS messages[/]: {why}", highlight=False)


def describe(selection: Any) -> str:
    said = {name: value for name, value in selection.metadata().items() if not name.endswith("_ns")}
    return ", ".join(f"{name} {value or 'any'}" for name, value in said.items())


def write_file(
    mcap: Path | None,
    bag: Path | None,
    partial: Path,
    records: Iterator[RecordedMessage],
    schemas: dict[str, Any],
    selection: Any,
    advance: Any,
) -> Any:
    if mcap is not None:
        from fleetbus.workers.recorder.mcap_export import export_mcap

        with partial.open("wb") as stream:
            return export_mcap(
                records,
                stream,
                on_each=lambda record: advance(),
                ros_schemas=schemas,
                metadata=selection.metadata(),
            )
    from fleetbus.workers.recorder.bag_export import export_bag

    return export_bag(records, partial, schemas, on_each=lambda record: advance())
