"""The recording process on its own, without the command line's weight.

``fleetbus recorder run`` checks its options and finds the ``fleetbus-recorder`` account's URL
(typer, rich, every command's module, the management API's client: about 13 MB of imports), then
replaces itself (``exec``: same process id, so the same signals reach it, and the death signal
``fleetbus worker`` asked for stays) with ``python -m fleetbus.workers.recorder``, which imports
only what recording needs. The process that records for hours never carries the command line
(``python -m bench.recorder --against REF`` compares its memory with an earlier commit's).

What the command resolved goes to the new image through an inherited pipe, as JSON: the URL holds
the account's password, which must not appear in the process's arguments (``ps``) or environment.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

from fleetbus.settings import Settings, load_settings
from fleetbus.workers.logs import configure_logging
from fleetbus.workers.recorder.consumer import RecorderOptions
from fleetbus.workers.recorder.filters import RoutingFilter
from fleetbus.workers.recorder.retention import parse_retention
from fleetbus.workers.recorder.runner import recorder_options, run_recorder

#: A pipe's buffer on Linux; the launch is written whole before the ``exec``, so it must fit.
PIPE_BUFFER = 65536


@dataclass(frozen=True)
class Launch:
    """What ``fleetbus recorder run`` hands the recording process."""

    url: str
    include: list[str] = field(default_factory=list)
    exclude: list[str] = field(default_factory=list)
    keep: list[str] = field(default_factory=list)
    sample_interval: float = 60.0
    verbose: bool = False

    def options(self, settings: Settings) -> RecorderOptions:
        """The settings' options with these overrides; raises ValueError naming a bad one."""
        overrides: dict[str, object] = {"sample_interval": self.sample_interval}
        if self.include or self.exclude:
            overrides["filter"] = RoutingFilter(
                tuple(self.include or settings.recorder_include),
                tuple(self.exclude or settings.recorder_exclude),
            )
        if self.keep:
            overrides["retention"] = parse_retention(self.keep)
        return recorder_options(settings, **overrides)


def exec_recorder(launch: Launch) -> None:
    """Replace this process with the recording process (does not return)."""
    data = json.dumps(asdict(launch)).encode()
    if len(data) >= PIPE_BUFFER:
        raise ValueError(f"the recorder's options are too long ({len(data)} bytes)")
    reading, writing = os.pipe()
    os.write(writing, data)
    os.close(writing)
    os.set_inheritable(reading, True)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(
        sys.executable,
        [sys.executable, "-m", "fleetbus.workers.recorder", "--launch-fd", str(reading)],
    )


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m fleetbus.workers.recorder",
        description="The recording process; started by `fleetbus recorder run`, which checks its options.",
    )
    parser.add_argument("--launch-fd", type=int, required=True, help="the pipe the launch is read from")
    args = parser.parse_args(argv)
    with os.fdopen(args.launch_fd, "rb") as pipe:
        launch = Launch(**json.loads(pipe.read()))
    settings = load_settings()
    options = launch.options(settings)
    configure_logging(launch.verbose)
    asyncio.run(run_recorder(settings, launch.url, options))
