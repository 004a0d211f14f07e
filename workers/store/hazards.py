"""The hazard registry and the team (robots, their localisation and service), kept by the
coordination service.

Hazards get an id sequential within their mission, assigned atomically by the store. A hazard
is ``held`` until the gate opens (:mod:`fleetbus.workers.team`) and a warden's inbox took it, ``announced``
once the wardens were told, then ``claimed`` by one warden, ``reached``, and finally ``cleared``.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from functools import cache
from typing import TYPE_CHECKING, Any

from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventRecord, StoreError

#: More hazards than any store holds: a page that starts past it is empty, without asking the
#: database to skip that many (SQLite's OFFSET takes 64 bits, mongoeco's skip 32).
MOST_HAZARDS = 2**31 - 1

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
    held_reason: str | None = None
    """While held with the gate open: why the last announcement did not count (no warden's inbox
    took it). The gate's own reasons are the team's state, read when asked (:mod:`fleetbus.workers.team`)."""
    version: int = 0
    """Grows with each change of its state where it is kept. At a site, central is sent each new
    version (:mod:`fleetbus.workers.hazard_uplink`); at central, a site's hazard holds the version
    the site sent last, and an older one is never applied over it."""
    site: str | None = None
    """At central: the site whose hazard this is; its state is the site's (its wardens are there).
    None: central's own hazard."""
    site_hazard_id: int | None = None
    """At central: the hazard's id at its site (central gives it an id of its own in the mission)."""

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
    """When its localisation state was last reported."""
    in_service: bool = True
    """False while an operator has taken it out of service: it neither blocks the hazard gate nor
    receives announcements."""
    service_changed_by: str | None = None
    """Who last took it out of service or put it back, and when (the audit record)."""
    service_changed_at: datetime | None = None
    catch_up: bool = False
    """Put back in service since the hazard service last sent it the open hazards it missed."""


@dataclass(frozen=True)
class Transition:
    """One step of a hazard's life: from which state, to which, and who may take it."""

    action: str
    sources: tuple[HazardState, ...]
    """The states it may be taken from."""
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


_S = HazardState
CLAIM = Transition("claimed", (_S.ANNOUNCED,), _S.CLAIMED, False, "claimed_at")
#: A claim while the gate is open, of a hazard announced or still held: its announcement may be on
#: its way (a hazard is marked announced once a warden's inbox took it, and that warden may claim it
#: first). One atomic step from either state, so the mark in between cannot make it fail.
CLAIM_WHILE_OPEN = Transition("claimed", (_S.ANNOUNCED, _S.HELD), _S.CLAIMED, False, "claimed_at")
RELEASE = Transition("released", (_S.CLAIMED,), _S.ANNOUNCED, True, None)
REACH = Transition("reached", (_S.CLAIMED,), _S.REACHED, True, "reached_at")
CLEAR = Transition("cleared", (_S.REACHED,), _S.CLEARED, True, "cleared_at")


if TYPE_CHECKING:
    from pydantic import TypeAdapter


@cache
def _timestamps() -> TypeAdapter[datetime]:
    # imported when first needed: the store's package is also imported by the recording process,
    # which keeps pydantic out of its memory
    from pydantic import TypeAdapter

    return TypeAdapter(datetime)


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
        from fleetbus.schemas.envelope import SCHEMA_VERSION

        event = {
            "message_id": record.message_id,
            "robot_id": record.robot_id,
            "epoch": record.epoch,
            "seq": record.seq,
            "sent_at": _timestamps().dump_python(record.sent_at, mode="json"),
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
    """Every hazard no warden's inbox has confirmed yet, in the order they were detected (id
    order): the held ones, and one a warden claimed on its way when the worker announcing it died
    before marking it (the other wardens may not have their copy: it goes again, claimed)."""
    wardens: list[RobotState]
    """Every warden of the team, in service or not: the gate's inputs (:func:`fleetbus.workers.team.gate`)."""


class HazardRefused(StoreError):
    """A claim, release or arrival the hazard's state does not allow; the message says why."""


class SiteApplied(str, Enum):
    """What central made of a site's hazard state (:meth:`CoordinationStore.apply_site_hazard`)."""

    APPLIED = "applied"
    """Registered, or newer than what central had: central shows it now."""
    STALE = "stale"
    """Central has this version or a newer one already (repeated, or overtaken): nothing changed."""
    NOT_THE_SITES = "not-the-sites"
    """Central has this hazard event as its own, or as another site's: the site may not set it."""


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
    async def set_in_service(self, name: str, in_service: bool, by: str, at: datetime) -> RobotState | None:
        """Take a robot out of service or put it back, recording who and when; put back, it is
        owed a catch-up (:attr:`RobotState.catch_up`). None: no such robot in the team."""

    @abc.abstractmethod
    async def caught_up(self, name: str) -> None:
        """The hazard service sent ``name`` the open hazards it missed: clear its catch-up."""

    @abc.abstractmethod
    async def remove_robot(self, name: str) -> bool:
        """Take a robot out of the team (its account is removed); False when it was not in it."""

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

    @abc.abstractmethod
    async def unannounced_hazards(self) -> list[Hazard]:
        """Hazards not marked announced yet, whatever their state (:attr:`HeldHazards.hazards`),
        by mission then id."""

    async def hold_hazards(self, new: Sequence[NewHazard]) -> HeldHazards:
        """Register ``new`` as held (idempotent, as :meth:`add_hazard`), then say what is held and
        whether the gate is open.

        The one place a hazard is registered, on every backend: called by the hazard service
        alone, which runs on the express lane's single active consumer, so a mission's ids are
        given in the order its hazards were stored (storing a batch registers none). Adapters
        that can do it in one transaction override this: it is on every hazard's way to the
        wardens."""
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
        waiting = await self.unannounced_hazards()
        return HeldHazards(waiting, await self.robots(RobotKind.WARDEN.value))

    @abc.abstractmethod
    async def mark_announced(self, hazards: list[Hazard], at: datetime) -> None:
        """Move these hazards from held to announced; one a warden claimed meanwhile keeps its state
        and gets its announcement time."""

    @abc.abstractmethod
    async def note_held(self, hazards: list[Hazard], reason: str) -> None:
        """Record why these hazards, still held, were not announced (:attr:`Hazard.held_reason`)."""

    @abc.abstractmethod
    async def get_hazard(self, mission_id: str, hazard_id: int) -> Hazard | None: ...

    @abc.abstractmethod
    async def open_hazards(self, mission_id: str | None) -> list[Hazard]:
        """Hazards not cleared, in id order (``None``: of every mission, by mission then id)."""

    @abc.abstractmethod
    async def recent_hazards(
        self, limit: int, offset: int = 0, state: HazardState | None = None
    ) -> list[Hazard]:
        """Every hazard (or those in ``state``), cleared ones too, of every mission, newest first
        (by the time it was received): ``limit`` of them after skipping the ``offset`` newest (any
        offset: one past :data:`MOST_HAZARDS` gives none)."""

    @abc.abstractmethod
    async def hazard_counts(self) -> dict[HazardState, int]:
        """How many hazards are in each state, of every mission (a state with none is left out)."""

    @abc.abstractmethod
    async def cleared_hazards(self, limit: int) -> list[Hazard]:
        """The ``limit`` hazards cleared last, of every mission, the last cleared first."""

    @abc.abstractmethod
    async def unsent_hazards(self, limit: int) -> list[Hazard]:
        """At a site: the store's own hazards (none of another site's) whose newest version is
        not marked sent (:meth:`mark_sent`), by mission then id, at most ``limit``."""

    @abc.abstractmethod
    async def mark_sent(self, hazards: Sequence[Hazard]) -> None:
        """Each of ``hazards`` is on its way to central at its :attr:`Hazard.version`: a version
        marked before is never marked back, a newer one stays unsent."""

    @abc.abstractmethod
    async def apply_site_hazard(self, site: str, hazard: Hazard) -> tuple[SiteApplied, Hazard | None]:
        """At central: take ``hazard`` as ``site`` has it (its id and version there) into the
        registry, atomically: registered under the mission's next id when central does not have its
        event yet, updated when its version is newer than central's, left alone when not
        (:attr:`SiteApplied.STALE`); refused when central has the event as its own hazard or as
        another site's. Returns what was done and the hazard as central has it now."""

    @abc.abstractmethod
    async def apply_transition(
        self, mission_id: str, hazard_id: int, warden: str, transition: Transition, at: datetime
    ) -> Hazard:
        """Apply one of the :data:`TRANSITIONS` atomically, or raise :class:`HazardRefused` (also
        for a site's hazard, whose steps are taken at its site)."""

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
    if hazard.site is not None:
        return HazardRefused(
            f"hazard {hazard_id} is site {hazard.site}'s (its hazard {hazard.site_hazard_id} there): "
            f"its wardens take its steps at the site; it cannot be {action} here"
        )
    if hazard.state is HazardState.HELD:
        return HazardRefused(
            f"hazard {hazard_id} is held until every warden is localised; it cannot be {action}"
        )
    if hazard.claimed_by and hazard.claimed_by != warden:
        return HazardRefused(f"hazard {hazard_id} is claimed by {hazard.claimed_by}")
    return HazardRefused(f"hazard {hazard_id} is {hazard.state.value}; {warden} cannot have it {action}")
