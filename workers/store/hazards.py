"""The hazard registry, its exchange with central (at a site, and at central), and the team it
follows (:mod:`fleetbus.workers.store.team`): one repository, :class:`CoordinationStore`, whose
consumers each take the part they use (:class:`~fleetbus.workers.store.team.TeamStore`,
:class:`HazardRegistry`, :class:`SiteHazardSync`).

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
from fleetbus.workers.store.port import (
    BOOL,
    COUNTERS,
    INTEGER,
    JSON,
    TEXT,
    TIME,
    Database,
    Doc,
    In,
    Index,
    Range,
    Schema,
)
from fleetbus.workers.store.team import Robots, RobotState, TeamStore

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

    def open_to(self, robot: str) -> bool:
        """Whether ``robot`` is given this hazard as open work (``hazard.open``, a warden's catch-up):
        not cleared, central's own (a site's are its wardens'), and not occupied by another warden
        (claimed or reached: the service keeps which hazards are occupied so that no other warden
        is sent to them)."""
        unclaimed_or_own = self.claimed_by is None or self.claimed_by == robot
        return self.state is not HazardState.CLEARED and self.site is None and unclaimed_or_own

    def shown_to(self, robot: str) -> bool:
        """Whether ``robot`` may look this hazard up (``hazard.get``): the robot that reported it,
        to follow what became of it, or a robot it is open to (:meth:`open_to`)."""
        return self.robot_id == robot or self.open_to(robot)

    def as_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["state"] = self.state.value
        for name in ("received_at", "announced_at", "claimed_at", "reached_at", "cleared_at"):
            out[name] = out[name].isoformat() if out[name] else None
        return out


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


class HazardRegistry(abc.ABC):
    """The hazards, from their registration to their clearing."""

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

    @abc.abstractmethod
    async def hold_hazards(self, new: Sequence[NewHazard]) -> HeldHazards:
        """Register ``new`` as held (idempotent, as :meth:`add_hazard`), then say what is held and
        whether the gate is open (the team's wardens).

        The one place a hazard is registered: called by the hazard service alone, which runs on
        the express lane's single active consumer, so a mission's ids are given in the order its
        hazards were stored (storing a batch registers none). It is on every hazard's way to the
        wardens: one unit of work, on the caller's thread on SQLite."""

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
    async def hazards_during(self, since: datetime, until: datetime, limit: int) -> list[Hazard]:
        """The hazards that existed at some moment of [since, until): received before ``until``
        and not cleared before ``since``; the ``limit`` received last, newest first (read by the
        (state, received_at) and (state, cleared_at) indexes)."""

    @abc.abstractmethod
    async def hazard_counts(self) -> dict[HazardState, int]:
        """How many hazards are in each state, of every mission (a state with none is left out)."""

    @abc.abstractmethod
    async def cleared_hazards(self, limit: int) -> list[Hazard]:
        """The ``limit`` hazards cleared last, of every mission, the last cleared first."""

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


class SiteHazardSync(abc.ABC):
    """The hazards a site sends central (its own, newest version first not yet sent), and those
    central takes in from its sites."""

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


class CoordinationStore(TeamStore, HazardRegistry, SiteHazardSync):
    """The team, the hazard registry and its exchange with central, on one database (a hazard
    is held until the team's wardens may have it)."""


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


HAZARDS = Schema(
    "hazards",
    {
        "mission_id": TEXT,
        "hazard_id": INTEGER,
        "robot_id": TEXT,
        "epoch": TEXT,
        "seq": INTEGER,
        "event": JSON,
        "state": TEXT,
        "received_at": TIME,
        "announced_at": TIME.maybe,
        "claimed_by": TEXT.maybe,
        "claimed_at": TIME.maybe,
        "reached_at": TIME.maybe,
        "cleared_at": TIME.maybe,
        "held_reason": TEXT.maybe,
        "version": INTEGER,
        "site": TEXT.maybe,
        "site_hazard_id": INTEGER.maybe,
        "unsent": BOOL,
    },
    key=("mission_id", "hazard_id"),
    indexes=(
        Index("robot_id", "epoch", "seq", unique=True),
        Index("mission_id", "hazard_id"),
        Index("state", "mission_id", "hazard_id"),
        Index("announced_at", "mission_id", "hazard_id"),
        Index("unsent", "mission_id", "hazard_id"),
        Index("received_at"),
        Index("state", "received_at"),
        Index("state", "cleared_at"),
    ),
)
"""A hazard, keyed by its mission and its id there, unique by its event; ``unsent`` until its
newest version is marked sent to central (:meth:`SiteHazardSync.mark_sent`)."""
FIELDS = [name for name in HAZARDS.fields if name != "unsent"]
BY_ID = ["mission_id", "hazard_id"]
#: The hazards received last first (then by mission and id, descending): the lists' order.
NEWEST_FIRST = ["-received_at", "-mission_id", "-hazard_id"]
OPEN = [state.value for state in HazardState if state is not HazardState.CLEARED]


def pruned_ids_counter(mission_id: str) -> str:
    """The counter of the highest hazard id of a mission whose hazard pruning removed: a new
    hazard's id stays above it, so that no id is given twice."""
    return f"hazard-ids:{mission_id}"


STATE_FIELDS = ("announced_at", "claimed_by", "claimed_at", "reached_at", "cleared_at", "held_reason")


def _hazard(doc: Doc) -> Hazard:
    return Hazard(**{name: doc[name] for name in FIELDS if name != "state"}, state=HazardState(doc["state"]))


def _key(hazard: Hazard) -> dict[str, Any]:
    return {"mission_id": hazard.mission_id, "hazard_id": hazard.hazard_id}


def _source(robot_id: str, epoch: str, seq: int) -> dict[str, Any]:
    return {"robot_id": robot_id, "epoch": epoch, "seq": seq}


class Coordination(Robots, CoordinationStore):
    """A hazard takes the next id of its mission by being inserted under it (the event's unique
    index and the key refuse a second): a worker that dies in between leaves no id unused. Every
    change of a hazard's state is one update conditional on the state it leaves, and gives it a
    new version."""

    def __init__(self, database: Database) -> None:
        super().__init__(database)
        self._hazards = database.collection(HAZARDS)
        self._counters = database.collection(COUNTERS)

    async def _find(self, where: dict[str, Any], **options: Any) -> list[Hazard]:
        return [_hazard(doc) for doc in await self._hazards.find(where, fields=FIELDS, **options)]

    async def _registered(self, robot_id: str, epoch: str, seq: int) -> Hazard | None:
        found = await self._find(_source(robot_id, epoch, seq))
        return found[0] if found else None

    async def _register(
        self, mission_id: str, source: dict[str, Any], fields: dict[str, Any]
    ) -> tuple[Hazard, bool]:
        """The hazard of ``source``'s event: the one registered, or a new one with ``fields`` under
        the mission's next id; and whether it is new."""
        while True:
            found = await self._registered(**source)
            if found is not None:
                return found, False
            last = await self._hazards.find(
                {"mission_id": mission_id}, order=["-hazard_id"], limit=1, fields=BY_ID
            )
            pruned = await self._counters.get(pruned_ids_counter(mission_id))
            next_id = max(last[0]["hazard_id"] if last else 0, pruned["last"] if pruned else 0) + 1
            doc = {"mission_id": mission_id, "hazard_id": next_id, **source, **fields}
            if (await self._hazards.insert([doc]))[0]:
                return _hazard(doc), True
            # the id, or this event, taken meanwhile: look again

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
        new = NewHazard(mission_id, robot_id, epoch, seq, event, received_at)
        return await self._database.transaction(lambda: self._add(new, held))

    async def _add(self, new: NewHazard, held: bool) -> Hazard:
        fields = {
            "event": new.event,
            "state": (HazardState.HELD if held else HazardState.ANNOUNCED).value,
            "received_at": new.received_at,
            **dict.fromkeys(STATE_FIELDS),
            "announced_at": None if held else new.received_at,
            "version": 0,
            "site": None,
            "site_hazard_id": None,
            "unsent": True,
        }
        hazard, _ = await self._register(new.mission_id, _source(new.robot_id, new.epoch, new.seq), fields)
        return hazard

    async def hold_hazards(self, new: Sequence[NewHazard]) -> HeldHazards:
        async def held() -> HeldHazards:
            return HeldHazards(await self.unannounced_hazards(), await self.robots(RobotKind.WARDEN.value))

        async def registered() -> HeldHazards | None:
            for hazard in new:
                if await self._registered(hazard.robot_id, hazard.epoch, hazard.seq) is None:
                    return None
            return await held()

        async def hold() -> HeldHazards:
            for hazard in new:
                await self._add(hazard, held=True)
            return await held()

        # a hazard held before (a redelivery) only reads: no write lock to wait for
        found = await self._database.snapshot(registered, urgent=True)
        return found if found is not None else await self._database.transaction(hold, urgent=True)

    async def held_hazards(self, mission_id: str | None = None) -> list[Hazard]:
        where = {"state": HazardState.HELD.value}
        if mission_id is not None:
            where["mission_id"] = mission_id
        return await self._find(where, order=BY_ID)

    async def unannounced_hazards(self) -> list[Hazard]:
        # a site's hazards are announced at their site, never here
        return await self._find({"announced_at": None, "site": None}, order=BY_ID)

    async def mark_announced(self, hazards: list[Hazard], at: datetime) -> None:
        async def mark() -> None:
            for hazard in hazards:
                key = _key(hazard)
                announced = {"state": HazardState.ANNOUNCED.value, "announced_at": at, "held_reason": None}
                changed = {"unsent": True}
                await self._hazards.update(
                    {**key, "state": HazardState.HELD.value}, {**announced, **changed}, add={"version": 1}
                )
                # one claimed by the first warden to get it, before this mark
                await self._hazards.update(
                    {**key, "announced_at": None}, {"announced_at": at, **changed}, add={"version": 1}
                )

        await self._database.transaction(mark, urgent=True)

    async def note_held(self, hazards: list[Hazard], reason: str) -> None:
        async def note() -> None:
            for hazard in hazards:
                await self._hazards.update(
                    {**_key(hazard), "state": HazardState.HELD.value}, {"held_reason": reason}
                )

        await self._database.transaction(note, urgent=True)

    async def get_hazard(self, mission_id: str, hazard_id: int) -> Hazard | None:
        found = await self._find({"mission_id": mission_id, "hazard_id": hazard_id})
        return found[0] if found else None

    async def open_hazards(self, mission_id: str | None) -> list[Hazard]:
        where: dict[str, Any] = {"state": In(OPEN)}
        if mission_id is not None:
            where["mission_id"] = mission_id
        return await self._find(where, order=BY_ID)

    async def recent_hazards(
        self, limit: int, offset: int = 0, state: HazardState | None = None
    ) -> list[Hazard]:
        if offset > MOST_HAZARDS:
            return []
        where = {"state": state.value} if state is not None else {}
        return await self._find(where, order=NEWEST_FIRST, limit=limit, skip=offset)

    async def hazards_during(self, since: datetime, until: datetime, limit: int) -> list[Hazard]:
        received = Range(lt=until)
        still_open = {"state": In(OPEN), "received_at": received}
        cleared = HazardState.CLEARED.value
        cleared_since = {"state": cleared, "cleared_at": Range(ge=since), "received_at": received}
        found = [
            *await self._find(still_open, order=NEWEST_FIRST, limit=limit),
            *await self._find(cleared_since, order=NEWEST_FIRST, limit=limit),
        ]
        found.sort(key=lambda hazard: (hazard.received_at, hazard.mission_id, hazard.hazard_id), reverse=True)
        return found[:limit]

    async def hazard_counts(self) -> dict[HazardState, int]:
        return {
            HazardState(state): group.count for state, group in (await self._hazards.group("state")).items()
        }

    async def cleared_hazards(self, limit: int) -> list[Hazard]:
        where = {"state": HazardState.CLEARED.value}
        return await self._find(where, order=["-cleared_at", "mission_id", "hazard_id"], limit=limit)

    async def unsent_hazards(self, limit: int) -> list[Hazard]:
        return await self._find({"unsent": True, "site": None}, order=BY_ID, limit=limit)

    async def mark_sent(self, hazards: Sequence[Hazard]) -> None:
        async def mark() -> None:
            for hazard in hazards:
                # only the version sent: a change since keeps it unsent
                await self._hazards.update({**_key(hazard), "version": hazard.version}, {"unsent": False})

        await self._database.transaction(mark, urgent=True)

    async def apply_site_hazard(self, site: str, hazard: Hazard) -> tuple[SiteApplied, Hazard | None]:
        state = {
            "state": hazard.state.value,
            **{name: getattr(hazard, name) for name in STATE_FIELDS},
            "version": hazard.version,
            "site_hazard_id": hazard.hazard_id,
        }

        async def apply() -> tuple[SiteApplied, Hazard | None]:
            source = _source(hazard.robot_id, hazard.epoch, hazard.seq)
            fields = {"event": hazard.event, "received_at": hazard.received_at, "site": site, "unsent": False}
            found, new = await self._register(hazard.mission_id, source, {**fields, **state})
            if new:
                return SiteApplied.APPLIED, found
            if found.site != site:
                return SiteApplied.NOT_THE_SITES, found
            newer = {**_key(found), "site": site, "version": Range(lt=hazard.version)}
            applied = await self._hazards.update(newer, state)
            return (SiteApplied.APPLIED if applied else SiteApplied.STALE), await self.get_hazard(
                found.mission_id, found.hazard_id
            )

        return await self._database.transaction(apply)

    async def apply_transition(
        self, mission_id: str, hazard_id: int, warden: str, transition: Transition, at: datetime
    ) -> Hazard:
        where: dict[str, Any] = {
            "mission_id": mission_id,
            "hazard_id": hazard_id,
            "state": In([source.value for source in transition.sources]),
            "site": None,  # a site's hazard takes its steps at its site (its state here is the site's)
        }
        if transition.claimer_only:
            where["claimed_by"] = warden
        change: dict[str, Any] = {"state": transition.target.value, "unsent": True}
        if transition.stamp is None:  # a release gives the claim up
            change.update(claimed_by=None, claimed_at=None)
        else:
            change[transition.stamp] = at
            if not transition.claimer_only:
                change["claimed_by"] = warden

        async def apply() -> Hazard:
            await self._hazards.update(where, change, add={"version": 1})
            hazard = await self.get_hazard(mission_id, hazard_id)
            if hazard is None or not transition.done_by(hazard, warden):
                raise refuse_transition(hazard, mission_id, hazard_id, transition.action, warden)
            return hazard

        return await self._database.transaction(apply)
