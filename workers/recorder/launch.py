"""The recording process on its own, without the command line's weight.

``fleetbus recorder run`` checks its options and finds the ``fleetbus-recorder`` account's URL
(typer, rich, every command's module, the management API's client: about 13 MB of imports), then
replaces itself (``exec``: same process id, so the same signals reach it, and the death signal
``fleetbus worker`` asked for stays) with ``python -m fleetbus.workers.recorder``, which imports
only what recording needs. The process that records for hours never carries the command line
(``python -m bench.recorder --against REF`` compares its memory with an earlier commit's).

What the command resolved goes to the new image through an inherited pipe, as JSON
(:mod:`fleetbus.launch_pipe`): the URL holds the account's password. The settings go resolved,
as plain values: the settings model (pydantic, pydantic-settings and the schemas it names: about
12 MB) stays out of the recording process.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleetbus.defaults import DEFAULT_RECORDER_SAMPLES_KEEP
from fleetbus.launch_pipe import exec_module, read_launch
from fleetbus.limits import parse_retention, parse_ttl
from fleetbus.workers.logs import configure_logging
from fleetbus.workers.recorder.consumer import RecorderOptions
from fleetbus.workers.recorder.filters import RoutingFilter
from fleetbus.workers.recorder.retention import samples_retention
from fleetbus.workers.recorder.runner import run_recorder

if TYPE_CHECKING:
    from fleetbus.settings import Settings


@dataclass(frozen=True)
class Stores:
    """Where the recording process records, and where the service's store is (the missions robots
    are recorded under, why a dead letter was refused): the settings' values, without the settings."""

    mongodb_url: str | None
    sqlite_path: Path
    recording_path: Path
    field_indexes_max: int

    @classmethod
    def of(cls, settings: Settings) -> Stores:
        return cls(
            settings.mongodb_url, settings.sqlite_path, settings.recording_path, settings.field_indexes_max
        )


@dataclass(frozen=True)
class Launch:
    """What ``fleetbus recorder run`` hands the recording process: its options and the settings
    it needs, resolved (:meth:`resolve`)."""

    url: str
    stores: Stores
    include: list[str] = field(default_factory=list)
    exclude: list[str] = field(default_factory=list)
    keep: list[str] = field(default_factory=list)
    max_message_bytes: int = 0
    sample_interval: float = 60.0
    samples_keep: str = DEFAULT_RECORDER_SAMPLES_KEEP
    ros_pieces_ttl: str = "1h"
    verbose: bool = False

    @classmethod
    def resolve(
        cls,
        settings: Settings,
        url: str,
        include: Sequence[str] = (),
        exclude: Sequence[str] = (),
        keep: Sequence[str] = (),
        sample_interval: float = 60.0,
        verbose: bool = False,
    ) -> Launch:
        """The command line's options, the settings' (``FLEETBUS_RECORDER_*``) where it gives none;
        raises ValueError naming a bad one."""
        launch = cls(
            url=url,
            stores=Stores.of(settings),
            include=list(include or settings.recorder_include),
            exclude=list(exclude or settings.recorder_exclude),
            keep=list(keep or settings.recorder_keep),
            max_message_bytes=settings.max_message_bytes,
            sample_interval=sample_interval,
            samples_keep=settings.recorder_samples_keep,
            ros_pieces_ttl=settings.ros_pieces_ttl,
            verbose=verbose,
        )
        launch.options()
        return launch

    def options(self) -> RecorderOptions:
        """The recorder's options; raises ValueError naming a bad one."""
        return RecorderOptions(
            filter=RoutingFilter(tuple(self.include), tuple(self.exclude)),
            retention=parse_retention(self.keep),
            max_message_bytes=self.max_message_bytes,
            sample_interval=self.sample_interval,
            samples_keep=samples_retention(self.samples_keep),
            ros_pieces_ttl=parse_ttl(self.ros_pieces_ttl, "FLEETBUS_ROS_PIECES_TTL"),
        )

    def to_json(self) -> bytes:
        return json.dumps(asdict(self), default=str).encode()

    @classmethod
    def from_json(cls, data: bytes) -> Launch:
        fields: dict[str, Any] = json.loads(data)
        stores = fields.pop("stores")
        for name in ("sqlite_path", "recording_path"):
            stores[name] = Path(stores[name])
        return cls(stores=Stores(**stores), **fields)


def exec_recorder(launch: Launch) -> None:
    """Replace this process with the recording process (does not return)."""
    exec_module("fleetbus.workers.recorder", launch.to_json())


def main(argv: Sequence[str] | None = None) -> None:
    launch = Launch.from_json(
        read_launch(
            "python -m fleetbus.workers.recorder",
            "The recording process; started by `fleetbus recorder run`, which checks its options.",
            argv,
        )
    )
    configure_logging(launch.verbose)
    asyncio.run(run_recorder(launch.stores, launch.url, launch.options()))
