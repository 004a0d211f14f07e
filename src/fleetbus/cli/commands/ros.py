"""``fleetbus ros``: the live bridge between a robot's ROS 1 master and fleetbus."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated

import typer

from fleetbus.cli.context import console, fail, settings
from fleetbus.cli.options import RobotUrl, check_url_option, robot_url
from fleetbus.processes import pid_alive

app = typer.Typer(help="The live ROS 1 bridge: ROS topics into fleetbus, notifications out as ROS topics.")


@app.command()
def bridge(
    robot: Annotated[str, typer.Argument(help="the robot's account (its fleetbus name)")],
    url: RobotUrl = None,
    mapping: Annotated[
        Path | None,
        typer.Option(help="the mapping file (default: FLEETBUS_ROS_MAPPING, else the standard mapping)"),
    ] = None,
) -> None:
    """Record every ROS topic of this robot's master in fleetbus, through the robot's outbox.

    Runs beside the ROS master (ROS_MASTER_URI), with the robot's credentials and state folder:
    what the broker has not confirmed waits in the outbox. Mapped topics become fleetbus events;
    this robot's notifications are published on /fleetbus/... topics. A part that fails (its ROS
    side, a thread) is started again, and `fleetbus ros status` shows it. Runs until interrupted;
    exits 1 when it cannot go on.
    """
    from dataclasses import asdict

    from fleetbus.publishers.ros.bridge import BridgeOptions
    from fleetbus.publishers.ros.launch import BridgeLaunch, exec_bridge
    from fleetbus.publishers.ros.mapping import MappingError, load_mapping

    check_url_option(url)
    config = settings()
    mapping_file = mapping or config.ros_mapping
    try:
        load_mapping(mapping_file)
    except MappingError as error:
        fail(str(error), code=2)
    options = BridgeOptions(
        python=config.ros_python,
        include=config.ros_include,
        exclude=config.ros_exclude,
        max_rate_hz=config.ros_max_rate_hz,
        discover_every_s=config.ros_discover_every_s,
        retry_most_s=config.ros_retry_most_s,
        queue=config.ros_queue,
        queue_bytes=config.ros_queue_bytes,
        blob_max=config.ros_blob_max_bytes,
        status_every_s=config.ros_status_every_s,
        linger_s=config.ros_linger_s,
        log_max_bytes=config.ros_log_max_bytes,
    )
    amqp_url = robot_url(robot, url)
    launch = BridgeLaunch(
        robot,
        amqp_url,
        str(config.robots_dir),
        str(mapping_file) if mapping_file else None,
        asdict(options),
    )
    # the same process bridges on without the command line's imports
    exec_bridge(launch)


@app.command()
def status(robot: Annotated[str, typer.Argument(help="the robot's account")]) -> None:
    """The counts of a robot's running (or last) bridge: per topic, recorded, as events, dropped and
    why; each part of the bridge (its ROS side, its writer, its notifications and commands), running
    or restarting after a failure. Exits 1 when a part is restarting, or the bridge failed or is gone."""
    from fleetbus.publishers.client import robot_folder
    from fleetbus.publishers.ros.bridge import STATUS_FILE

    path = robot_folder(settings().robots_dir, robot) / STATUS_FILE
    if not path.exists():
        fail(f"no bridge has run for {robot!r} here ({path} does not exist)")
    status = json.loads(path.read_text())
    ended = str(status.get("ros_side", "")).startswith("ended")
    gone = not ended and not pid_alive(status.get("pid"))
    if gone:
        status["ros_side"] = f"not running: the bridge (pid {status.get('pid')}) is gone"
    console.print_json(json.dumps(status))
    failing = [name for name, part in status.get("parts", {}).items() if part.get("state") == "restarting"]
    if failing or gone or status.get("ended"):
        raise typer.Exit(1)


@app.command("mapping")
def show_mapping() -> None:
    """Print the standard mapping file (a start for your own)."""
    from fleetbus.publishers.ros.mapping import standard_mapping_text

    print(standard_mapping_text(), end="")


@app.command()
def replay(
    robot: Annotated[str, typer.Argument(help="the robot whose recorded ROS messages are replayed")],
    since: Annotated[str | None, typer.Option(help="recorded from this time (as `fleetbus export`)")] = None,
    until: Annotated[str | None, typer.Option(help="recorded before this time")] = None,
    topics: Annotated[
        list[str] | None, typer.Option("--topic", help="only this topic; `*` and `?` match (repeatable)")
    ] = None,
    speed: Annotated[float, typer.Option(min=0.001, help="faster (2) or slower (0.5) than recorded")] = 1.0,
    subscribers: Annotated[
        int, typer.Option(min=0, help="wait until each topic has this many subscribers before starting")
    ] = 0,
    delay: Annotated[
        float, typer.Option(min=0, help="seconds between advertising and the first message (rosbag play's)")
    ] = 0.2,
    prefix: Annotated[str, typer.Option(help="publish under this namespace, e.g. /replay")] = "",
) -> None:
    """Publish a recorded window of the robot's ROS messages on the ROS master (ROS_MASTER_URI), as
    their original topics and types, at the recorded pace (or --speed times it)."""
    from fleetbus.api.services.errors import ServiceRefusal
    from fleetbus.cli.services import fail_refused, recording_stream, with_recording
    from fleetbus.cli.times import parse_time_ns
    from fleetbus.workers.recorder.export_selection import Selection
    from fleetbus.workers.recorder.ros_replay import ReplayError, ReplayOptions, replay_into_ros

    if prefix and (not prefix.startswith("/") or prefix.endswith("/")):
        fail(f"--prefix {prefix!r}: a namespace starts with '/' and does not end with one", code=2)
    try:
        window = parse_time_ns(since, "--since"), parse_time_ns(until, "--until")
        selection = Selection((robot,), ("ros",), tuple(topics or ()), *window)
    except ValueError as error:  # the recording's refusal of the window
        fail(str(error), code=2)
    schemas = with_recording(lambda recording: recording.ros_schemas(selection))
    python = settings().ros_python
    options = ReplayOptions(python, speed, subscribers, delay_s=delay, prefix=prefix, env=dict(os.environ))
    try:
        with (
            recording_stream(lambda recording: recording.selected(selection)) as survey,
            recording_stream(lambda recording: recording.selected(selection)) as records,
        ):
            report = replay_into_ros(survey, records, schemas, options)
    except ReplayError as error:
        fail(str(error))
    except ServiceRefusal as refusal:
        fail_refused(refusal)
    total = sum(report.published.values())
    console.print(f"replayed {total} messages of {robot} on {len(report.published)} topics")
    for why, count in report.left_out.items():
        console.print(f"[yellow]left out {count}[/]: {why}", highlight=False)
