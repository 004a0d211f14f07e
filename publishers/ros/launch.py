"""The bridge's process on its own, without the command line's weight.

``fleetbus ros bridge`` checks its options (the mapping file, the robot's URL), then replaces
itself (:mod:`fleetbus.launch_pipe`) with ``python -m fleetbus.publishers.ros``, which imports
only what bridging needs: no typer, rich or settings model in the process that runs for days
beside the robot (decision 0016 says what the rest costs).
"""

from __future__ import annotations

import json
import logging
import signal
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from fleetbus.launch_pipe import exec_module, read_launch

#: The status of a bridge that could not start (as the command line's failures).
FAILED = 1


@dataclass(frozen=True)
class BridgeLaunch:
    """What ``fleetbus ros bridge`` resolved: the robot, its URL (with its password: through the
    pipe only), its state folder, the mapping file, and the bridge's options."""

    robot: str
    url: str
    robots_dir: str
    mapping: str | None
    options: dict[str, Any] = field(default_factory=dict)
    """:class:`~fleetbus.publishers.ros.bridge.BridgeOptions`' fields."""
    connect_timeout: float = 10.0

    def to_json(self) -> bytes:
        return json.dumps(asdict(self)).encode()

    @classmethod
    def from_json(cls, data: bytes) -> BridgeLaunch:
        return cls(**json.loads(data))


def exec_bridge(launch: BridgeLaunch) -> None:
    """Replace this process with the bridge's (does not return)."""
    exec_module("fleetbus.publishers.ros", launch.to_json())


def run(launch: BridgeLaunch) -> int:
    """Bridge until SIGTERM or Ctrl-C (0), or until the bridge cannot go on (not 0)."""
    from fleetbus.publishers.client import RobotClient
    from fleetbus.publishers.ros.bridge import Bridge, BridgeOptions, RosSideError
    from fleetbus.publishers.ros.mapping import MappingError, load_mapping
    from fleetbus.publishers.state_lock import RobotStateInUse

    def failed(message: str) -> int:
        print(f"error: {message}", file=sys.stderr)
        return FAILED

    try:
        rules = load_mapping(Path(launch.mapping) if launch.mapping else None)
    except MappingError as error:
        return failed(str(error))
    options = {k: tuple(v) if isinstance(v, list) else v for k, v in launch.options.items()}
    try:
        state = Path(launch.robots_dir)
        client = RobotClient(launch.url, state_dir=state, connect_timeout=launch.connect_timeout)
    except RobotStateInUse as error:
        return failed(str(error))
    try:
        if client.robot_id != launch.robot:
            return failed(f"the URL logs in as {client.robot_id!r}, not {launch.robot!r}")
        runner = Bridge(client, rules, BridgeOptions(**options), state, commands_url=launch.url)
        signal.signal(signal.SIGTERM, lambda *_: runner.stop())
        try:
            return runner.run()
        except RosSideError as error:
            return failed(str(error))
        except KeyboardInterrupt:
            runner.stop()
            return 0
    finally:
        client.close()


def main(argv: Sequence[str] | None = None) -> None:
    data = read_launch(
        "python -m fleetbus.publishers.ros",
        "The ROS bridge's process; started by `fleetbus ros bridge`, which checks its options.",
        argv,
    )
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sys.exit(run(BridgeLaunch.from_json(data)))
