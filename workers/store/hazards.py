"""The hazard registry and the robots' localisation states, kept by the coordination service.

Hazards get an id sequential within their mission, assigned atomically by the store. A hazard
is ``held`` while some warden of the team is not localised, ``announced`` once the wardens were
told, then ``claimed`` by one warden, ``reached``, and finally ``cleared``.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from typing import Any

from pydantic import TypeAdapter

from schemas.envelope import SCHEMA_VERSION
from schemas.routing import RobotKind
from workers.store.base import EventRecord, StoreError

DEFAULT_MISSION = "default"


class HazardState(str, Enum):
    HELD = "held"
    ANNOUNCED = "announced"
    CLAIMED = "claimed"
    REACHED = "reached"
    CLEARED = "cleared"


@dataclass(frozen=True)
class Hazard:
    mission_id: str
    hazard_id: int
    robot_id: str
    epoch: str
    seq: int
    event: dict[str, Any]
    """The hazard event as the robot sent it (envelope and body, JSON types)."""
    state: HazardState
    received_at: datetime
    announced_at: datetime | None = None
    claimed_by: str | None = None
    claimed_at: datetime | None = None
    reached_at: datetime | None = None
    cleared_at: datetime | None = None

    def as_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["state"] = self.state.value
        for name in ("received_at", "announced_at", "claimed_at", "reached_at", "cleared_at"):
            out[name] = out[name].isoformat() if out[name] else None
        return out


@dataclass(frozen=True)
class RobotState:
    name: str
    kind: str | None
    localised: bool
    updated_at: datetime | None


@dataclass(frozen=True)
class Transition:
    """One step of a hazard's life: from which state, to which, and who may take it."""

    action: str
    source: HazardState
    target: HazardState
    claimer_only: bool
    """Only the warden holding the claim may take this step."""
    stamp: str | None
    """The time field this step sets; ``None`` for a release, which clears the claim."""

    def done_by(self, hazard: Hazard, warden: str) -> bool:
        """Whether ``hazard`` shows this step taken by ``warden`` (after an atomic update)."""
        if self.target is HazardState.ANNOUNCED:
            return hazard.state is HazardState.ANNOUNCED
        return hazard.state is self.target and hazard.claimed_by == warden


CLAIM = Transition("claimed", HazardState.ANNOUNCED, HazardState.CLAIMED, False, "claimed_at")
RELEASE = Transition("released", HazardState.CLAIMED, HazardState.ANNOUNCED, True, None)
REACH = Transition("reached", HazardState.CLAIMED, HazardState.REACHED, True, "reached_at")
CLEAR = Transition("cleared", HazardState.REACHED, HazardState.CLEARED, True, "cleared_at")


_TIMESTAMP: TypeAdapter[datetime] = TypeAdapter(datetime)


@dataclass(frozen=True)
class NewHazard:
    """A hazard event to register as held (see :meth:`CoordinationStore.hold_hazards`)."""

    mission_id: str
    robot_id: str
    epoch: str
    seq: int
    event: dict[str, Any]
    received_at: datetime

    @classmethod
    def of(cls, record: EventRecord) -> NewHazard:
        """The hazard a stored hazard event registers, in its mission (the default one when its
        robot is on none); ``event`` is the event as the robot sent it, in JSON types, rebuilt from
        the record exactly as pydantic dumps it, so the store can register it by itself."""
        event = {
            "message_id": record.message_id,
            "robot_id": record.robot_id,
            "epoch": record.epoch,
            "seq": record.seq,
            "sent_at": _TIMESTAMP.dump_python(record.sent_at, mode="json"),
            "schema_version": SCHEMA_VERSION,
            "type": record.type,
            "body": record.body,
        }
        return cls(
            record.mission_id or DEFAULT_MISSION,
            record.robot_id,
            record.epoch,
            record.seq,
            event,
            record.received_at,
        )


@dataclass(frozen=True)
class HeldHazards:
    hazards: list[Hazard]
    """Every held hazard, in the order they were detected (id order)."""
    wardens_localised: bool
    """Whether every warden of the team reports itself localised: the gate is open."""


class HazardRefused(StoreError):
    """A claim, release or arrival the hazard's state does not allow; the message says why."""


class CoordinationStore(abc.ABC):
    @abc.abstractmethod
    async def register_robot(self, name: str, kind: str | None) -> None:
        """Record a robot and its kind (explorer, warden, guide); idempotent."""

    @abc.abstractmethod
    async def set_localised(self, name: str, localised: bool, at: datetime) -> None:
        """Record a robot's localisation state (an unknown robot is recorded without a kind)."""

    @abc.abstractmethod
    async def robots(self, kind: str | None = None) -> list[RobotState]: ...

    @abc.abstractmethod
    async def add_hazard(
        self,
        mission_id: str,
        robot_id: str,
        epoch: str,
        seq: int,
        event: dict[str, Any],
        received_at: datetime,
        held: bool,
    ) -> Hazard:
        """Register the hazard of event (robot_id, epoch, seq) with the mission's next id.

        Idempotent: the same event again returns the hazard registered the first time.
        """

    @abc.abstractmethod
    async def held_hazards(self, mission_id: str | None = None) -> list[Hazard]:
        """Held hazards in the order they were detected (id order)."""

    async def hold_hazards(self, new: Sequence[NewHazard]) -> HeldHazards:
        """Register ``new`` as held (idempotent, as :meth:`add_hazard`), then say what is held and
        whether the gate is open. Adapters that can do it in one transaction override this: it is
        on every hazard's way to the wardens."""
        for hazard in new:
            await self.add_hazard(
                hazard.mission_id,
                hazard.robot_id,
                hazard.epoch,
                hazard.seq,
                hazard.event,
                hazard.received_at,
                held=True,
            )
        held = await self.held_hazards()
        wardens = await self.robots(RobotKind.WARDEN.value)
        return HeldHazards(held, all(warden.localised for warden in wardens))

    @abc.abstractmethod
    async def mark_announced(self, hazards: list[Hazard], at: datetime) -> None:
        """Move these hazards from held to announced (others are left as they are)."""

    @abc.abstractmethod
    async def get_hazard(self, mission_id: str, hazard_id: int) -> Hazard | None: ...

    @abc.abstractmethod
    async def open_hazards(self, mission_id: str) -> list[Hazard]:
        """Hazards not cleared, in id order."""

    @abc.abstractmethod
    async def apply_transition(
        self, mission_id: str, hazard_id: int, warden: str, transition: Transition, at: datetime
    ) -> Hazard:
        """Apply one of the :data:`TRANSITIONS` atomically, or raise :class:`HazardRefused`."""

    async def claim(self, mission_id: str, hazard_id: int, warden: str, at: datetime) -> Hazard:
        """Give an announced hazard to ``warden``; atomic, so of two claims one wins."""
        return await self.apply_transition(mission_id, hazard_id, warden, CLAIM, at)

    async def release(self, mission_id: str, hazard_id: int, warden: str, at: datetime) -> Hazard:
        """The claiming warden gives the hazard up; it is announced again."""
        return await self.apply_transition(mission_id, hazard_id, warden, RELEASE, at)

    async def mark_reached(self, mission_id: str, hazard_id: int, warden: str, at: datetime) -> Hazard:
        """The claiming warden reports it reached the hazard."""
        return await self.apply_transition(mission_id, hazard_id, warden, REACH, at)

    async def mark_cleared(self, mission_id: str, hazard_id: int, warden: str, at: datetime) -> Hazard:
        """The warden that reached the hazard reports it cleared; it leaves the open hazards."""
        return await self.apply_transition(mission_id, hazard_id, warden, CLEAR, at)


def refuse_transition(
    hazard: Hazard | None, mission_id: str, hazard_id: int, action: str, warden: str
) -> HazardRefused:
    """The error for an action the hazard's current state does not allow."""
    if hazard is None:
        return HazardRefused(f"no hazard {hazard_id} in mission {mission_id!r}")
    if hazard.state is HazardState.HELD:
        return HazardRefused(
            f"hazard {hazard_id} is held until every warden is localised; it cannot be {action}"
        )
    if hazard.claimed_by and hazard.claimed_by != warden:
        return HazardRefused(f"hazard {hazard_id} is claimed by {hazard.claimed_by}")
    return HazardRefused(f"hazard {hazard_id} is {hazard.state.value}; {warden} cannot have it {action}")
