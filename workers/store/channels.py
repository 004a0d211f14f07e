"""Channel state: which operator has mounted which robot for which mission, who is checked in.

A robot is booked by at most one mount; an operator by at most one mission at a time (its
mounts and its check-in all belong to that mission). Booking is atomic in the store, so of two
operators mounting the same robot one wins. A robot's data is recorded under a mission while
the operator who mounted it for that mission is checked in to it. Every change of these
channels is itself recorded: who did what, to which robot, in which mission, when.
"""

from __future__ import annotations

import abc
from collections.abc import Collection
from dataclasses import dataclass
from datetime import datetime
from enum import Enum

from fleetbus.workers.store.base import StoreError


class ChannelAction(str, Enum):
    MOUNT = "mount"
    UNMOUNT = "unmount"
    FORCE_UNMOUNT = "force-unmount"
    CHECK_IN = "check-in"
    CHECK_OUT = "check-out"
    REPAIR = "repair"


@dataclass(frozen=True)
class Mount:
    robot: str
    operator: str
    mission_id: str
    mounted_at: datetime


@dataclass(frozen=True)
class CheckIn:
    operator: str
    mission_id: str
    checked_in_at: datetime


@dataclass(frozen=True)
class ChannelChange:
    at: datetime
    actor: str
    action: ChannelAction
    mission_id: str | None
    operator: str | None
    robot: str | None
    detail: str = ""


class Booked(StoreError):
    """The robot or the operator is booked by another mission (or the robot by another operator)."""


class ChannelStore(abc.ABC):
    @abc.abstractmethod
    async def mount(self, robot: str, operator: str, mission_id: str, at: datetime) -> Mount:
        """Book ``robot`` for ``operator`` in the mission; idempotent; raise :class:`Booked`."""

    @abc.abstractmethod
    async def unmount(self, robot: str, operator: str | None = None) -> Mount | None:
        """Remove the robot's mount (only ``operator``'s, when given); the removed mount, or None."""

    @abc.abstractmethod
    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        """Current mounts, by robot."""

    @abc.abstractmethod
    async def check_in(self, operator: str, mission_id: str, at: datetime) -> CheckIn:
        """Check the operator in; idempotent; raise :class:`Booked` if it is booked elsewhere."""

    @abc.abstractmethod
    async def check_out(self, operator: str, mission_id: str) -> bool:
        """Check the operator out of the mission; False when it was not checked in there."""

    @abc.abstractmethod
    async def check_ins(
        self, mission_id: str | None = None, operator: str | None = None
    ) -> list[CheckIn]: ...

    @abc.abstractmethod
    async def recording_missions(self, robots: Collection[str]) -> dict[str, str]:
        """For each of ``robots`` whose data is being recorded now: the mission it is recorded under."""

    @abc.abstractmethod
    async def record_change(self, change: ChannelChange) -> None: ...

    @abc.abstractmethod
    async def channel_changes(
        self, mission_id: str | None = None, limit: int | None = None
    ) -> list[ChannelChange]:
        """Recorded changes, oldest first (the newest ``limit`` when given)."""
