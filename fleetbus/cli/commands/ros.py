"""``fleetbus ros``: the live bridge between a robot's ROS 1 master and fleetbus."""

from __future__ import annotations

import json
import logging
import os
import signal
from pathlib import Path
from typing import Annotated

import typer

from fleetbus.cli.commands.events import check_url_option, open_robot, robot_url
from fleetbus.cli.context import console, fail, settings
from fleetbus.processes import pid_alive

app = typer.Typer(help="The live ROS 1 bridge: ROS topics into fleetbus, notifications out as ROS topics.")


@app.command()
def bridge(
    robot: Annotated[str, typer.Argument(help="the robot's account (its fleetbus name)")],
    url: Annotated[
        str | None,
        typer.Option(
            help="the robot's AMQP URL without a password (a client certificate's; default: "
            "FLEETBUS_ROBOT_URL, else the one `users add` kept)"
        ),
    ] = None,
    mapping: Annotated[
        Path | None,
        typer.Option(help="the mapping file (default: FLEETBUS_ROS_MAPPING, else the standard mapping)"),
    ] = None,
) -> None:
    """Record every ROS topic of this robot's master in fleetbus, through the robot's outbox.

    Runs beside the ROS master (ROS_MASTER_URI), with the robot's credentials and state folder:
    what the broker has not confirmed waits in the outbox. Mapped topics become fleetbus events;
    this robot's notifications are published on /fleetbus/... topics. Runs until interrupted.
    """
    from fleetbus.publishers.ros.bridge import Bridge, BridgeOptions, RosSideError
    from fleetbus.publishers.ros.mapping import MappingError, load_mapping

    check_url_option(url)
    config = settings()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        rules = load_mapping(mapping or config.ros_mapping)
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
        blob_max=config.ros_blob_max_bytes,
        status_every_s=config.ros_status_every_s,
        linger_s=config.ros_linger_s,
    )
    amqp_url = robot_url(robot, url)
    client = open_robot(robot, amqp_url, 10.0)
    runner = Bridge(client, rules, options, config.robots_dir, commands_url=amqp_url)
    signal.signal(signal.SIGTERM, lambda *_: runner.stop())
    try:
        code = runner.run()
    except RosSideError as error:
        fail(str(error))
    except KeyboardInterrupt:
        runner.stop()
        code = 0
    finally:
        client.close()
    raise typer.Exit(code)


@app.command()
def status(robot: Annotated[str, typer.Argument(help="the robot's account")]) -> None:
    """The counts of a robot's running (or last) bridge: per topic, recorded, as events, dropped and why."""
    from fleetbus.publishers.client import robot_folder
    from fleetbus.publishers.ros.bridge import STATUS_FILE

    path = robot_folder(settings().robots_dir, robot) / STATUS_FILE
    if not path.exists():
        fail(f"no bridge has run for {robot!r} here ({path} does not exist)")
    status = json.loads(path.read_text())
    if status.get("ros_side") == "running" and not pid_alive(status.get("pid")):
        status["ros_side"] = f"not running: the bridge (pid {status.get('pid')}) is gone"
    console.print_json(json.dumps(status))


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
    from fleetbus.cli.commands.bags import known_robots_and_schemas, selected
    from fleetbus.cli.context import recording_stream, with_recording
    from fleetbus.cli.times import parse_time_ns
    from fleetbus.workers.recorder.export_selection import Selection
    from fleetbus.workers.recorder.ros_replay import ReplayError, ReplayOptions, replay_into_ros
    from fleetbus.workers.store.recordings import RecordingError

    if prefix and (not prefix.startswith("/") or prefix.endswith("/")):
        fail(f"--prefix {prefix!r}: a namespace starts with '/' and does not end with one", code=2)
    try:
        window = parse_time_ns(since, "--since"), parse_time_ns(until, "--until")
        selection = Selection((robot,), ("ros",), tuple(topics or ()), *window)
        schemas = with_recording(lambda store: known_robots_and_schemas(store, selection))
    except RecordingError as error:
        fail(str(error), code=2)
    python = settings().ros_python
    options = ReplayOptions(python, speed, subscribers, delay_s=delay, prefix=prefix, env=dict(os.environ))
    try:
        with (
            recording_stream(lambda store: selected(store, selection)) as survey,
            recording_stream(lambda store: selected(store, selection)) as records,
        ):
            report = replay_into_ros(survey, records, schemas, options)
    except ReplayError as error:
        fail(str(error))
    total = sum(report.published.values())
    console.print(f"replayed {total} messages of {robot} on {len(report.published)} topics")
    for why, count in report.left_out.items():
        console.print(f"[yellow]left out {count}[/]: {why}", highlight=False)
