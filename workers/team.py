"""The team the hazard gate follows: who counts for it, whether it is open, and why a hazard waits.

Seed 000's rule: hazards are held until every warden is localised. Here "every warden" means every
warden of the team *in service*, and there must be at least one: with none, a hazard would be
announced to nobody, so it stays held until the first wardens join and localise. A warden whose
account is removed leaves the team; an operator can take a warden out of service (it no longer
blocks the gate, and is sent nothing) and put it back (the hazard service then sends it the open
hazards it missed, before anything newer).

The rule is here once: the hazard service decides with :func:`gate`; ``fleetbus team``,
``fleetbus hazards`` and ``GET /team`` explain with the same function.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Any

from fleetbus.broker.team_changes import tell_hazard_service
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.schemas.team import TeamChange, TeamChangeKind
from fleetbus.workers.store.base import EventRecord, EventStore
from fleetbus.workers.store.hazards import Hazard, HazardState, RobotState
from fleetbus.workers.store.team import TeamStore

NO_WARDEN = "no warden in the team"


def counts_for_gate(robot: RobotState) -> bool:
    """A warden in service: the gate waits for it, and announcements go to it."""
    return robot.kind == RobotKind.WARDEN.value and robot.in_service


@dataclass(frozen=True)
class Gate:
    wardens: list[str]
    """The wardens in service: who the announcements go to."""
    waiting_for: list[str] = field(default_factory=list)
    """Wardens in service that are not localised."""
    out_of_service: list[str] = field(default_factory=list)

    @property
    def open(self) -> bool:
        return bool(self.wardens) and not self.waiting_for


def gate(team: Sequence[RobotState]) -> Gate:
    """The gate for ``team`` (any robots: only wardens matter)."""
    wardens = [robot for robot in team if robot.kind == RobotKind.WARDEN.value]
    serving = [robot for robot in wardens if counts_for_gate(robot)]
    return Gate(
        [robot.name for robot in serving],
        [robot.name for robot in serving if not robot.localised],
        [robot.name for robot in wardens if not robot.in_service],
    )


def ago(moment: datetime | None, now: datetime) -> str:
    """``never``, ``12 s ago``, ``4 min ago``, ``3 h ago``, ``2 days ago``."""
    if moment is None:
        return "never"
    seconds = max(0, int((now - moment).total_seconds()))
    if seconds < 120:
        return f"{seconds} s ago"
    if seconds < 7200:
        return f"{seconds // 60} min ago"
    if seconds < 172_800:
        return f"{seconds // 3600} h ago"
    return f"{seconds // 86_400} days ago"


def why_closed(
    state: Gate, last_seen: Mapping[str, datetime | None] | None = None, now: datetime | None = None
) -> str | None:
    """Why the gate holds hazards, or None when it is open; with ``last_seen`` (and ``now``), when
    each warden it waits for was last heard from."""
    if state.open:
        return None
    if not state.wardens:
        if state.out_of_service:
            return f"no warden in service ({', '.join(state.out_of_service)} out of service)"
        return NO_WARDEN
    if last_seen is None or now is None:
        return f"waiting for {', '.join(state.waiting_for)}: not localised"
    return "; ".join(
        f"waiting for {name}: not localised, last seen {ago(last_seen.get(name), now)}"
        for name in state.waiting_for
    )


def why_held(hazard: Hazard, state: Gate, last_seen: Mapping[str, datetime | None], now: datetime) -> str:
    """Why ``hazard`` is still held: the gate, or with the gate open, what its announcement met. A
    site's hazard waits for its site's gate, not this one: what its site said, if anything."""
    if hazard.state is not HazardState.HELD:
        return ""
    if hazard.site is not None:
        return f"held at site {hazard.site}" + (f": {hazard.held_reason}" if hazard.held_reason else "")
    closed = why_closed(state, last_seen, now)
    if closed:
        return closed
    return hazard.held_reason or "the gate is open: waiting for the hazard service (is a worker running?)"


@dataclass(frozen=True)
class TeamMember:
    robot: RobotState
    last_seen: datetime | None
    """When the service last received an event of it (any type; its newest event's arrival)."""
    stale: bool
    """Silent longer than ``FLEETBUS_STALE_AFTER_S`` (or never heard)."""
    outbox_dropped: dict[str, int] = field(default_factory=dict)
    """What the robot's outbox dropped so far by type (its thinning policy), as its newest status said."""

    @property
    def counts_for_gate(self) -> bool:
        return counts_for_gate(self.robot)

    def as_dict(self) -> dict[str, Any]:
        robot = self.robot
        return {
            "name": robot.name,
            "kind": robot.kind,
            "localised": robot.localised,
            "last_seen": self.last_seen.isoformat() if self.last_seen else None,
            "stale": self.stale,
            "in_service": robot.in_service,
            "counts_for_gate": self.counts_for_gate,
            "service_changed_by": robot.service_changed_by,
            "service_changed_at": robot.service_changed_at.isoformat() if robot.service_changed_at else None,
            "outbox_dropped": self.outbox_dropped,
        }


def team_member(
    robot: RobotState,
    seen: datetime | None,
    now: datetime,
    stale_after: timedelta,
    outbox_dropped: dict[str, int] | None = None,
) -> TeamMember:
    """``robot``, last heard from at ``seen``: stale when silent over ``stale_after`` or never heard."""
    return TeamMember(robot, seen, seen is None or now - seen > stale_after, outbox_dropped or {})


def dropped_by(status: EventRecord | None) -> dict[str, int]:
    """What a robot's outbox dropped, as its status event ``status`` says."""
    return dict((status.body.get("outbox_dropped") or {}) if status is not None else {})


async def team_members(
    robots: Sequence[RobotState], events: EventStore, now: datetime, stale_after: timedelta
) -> list[TeamMember]:
    """``robots`` (a page of the team) with when each was last heard from and what its outbox
    dropped: two queries however many robots and events (:meth:`EventStore.newest_events`)."""
    names = [robot.name for robot in robots]
    newest = await events.newest_events(names)
    statuses = await events.newest_events(names, EventType.STATUS.value)
    return [
        team_member(
            robot,
            newest[robot.name].received_at if robot.name in newest else None,
            now,
            stale_after,
            dropped_by(statuses.get(robot.name)),
        )
        for robot in robots
    ]


async def read_team(
    team: TeamStore,
    events: EventStore,
    now: datetime,
    stale_after: timedelta,
    *,
    offset: int = 0,
    limit: int | None = None,
) -> list[TeamMember]:
    """The robots of the team, by name (``limit`` of them from ``offset``: a page), each with
    when it was last heard from and what its outbox dropped; three queries in all."""
    robots = await team.robots()
    page = robots[offset : None if limit is None else offset + limit]
    return await team_members(page, events, now, stale_after)


async def last_seen_of(events: EventStore, names: Sequence[str]) -> dict[str, datetime | None]:
    """When each of ``names`` was last heard from (one query)."""
    newest = await events.newest_events(names)
    return {name: newest[name].received_at if name in newest else None for name in names}


class TeamRefused(Exception):
    """A team change that cannot be made; the message says why."""


class NotInTeam(TeamRefused):
    pass


class NotAWarden(TeamRefused):
    pass


async def set_in_service(team: TeamStore, name: str, in_service: bool, by: str, at: datetime) -> RobotState:
    """Take a warden out of service, or put it back; refused for a robot not in the team or not a
    warden (only wardens count for the gate and receive announcements)."""
    known = {robot.name: robot for robot in await team.robots()}
    robot = known.get(name)
    if robot is None:
        raise NotInTeam(f"{name} is not in the team (known: {', '.join(sorted(known)) or 'none'})")
    if robot.kind != RobotKind.WARDEN.value:
        raise NotAWarden(f"{name} is {_a(robot.kind)}: only wardens are taken out of service")
    changed = await team.set_in_service(name, in_service, by, at)
    if changed is None:  # removed meanwhile
        raise NotInTeam(f"{name} is not in the team")
    return changed


async def change_service(team: TeamStore, admin_url: str, name: str, in_service: bool, by: str) -> RobotState:
    """Take a warden out of service or put it back (recorded with ``by`` and the time), then tell
    the hazard service: without the warden the gate may open; put back, it is owed what it missed.
    Raises :class:`TeamRefused`, or ``HazardServiceNotTold`` (the change is stored; repeat it)."""
    at = datetime.now(timezone.utc)
    robot = await set_in_service(team, name, in_service, by, at)
    change = TeamChange(
        robot=name, change=TeamChangeKind.IN if in_service else TeamChangeKind.OUT, by=by, at=at
    )
    await asyncio.to_thread(tell_hazard_service, admin_url, change)
    return robot


async def leave_team(team: TeamStore, admin_url: str, name: str, by: str) -> bool:
    """Take a robot whose account is removed out of the team; a warden's leaving is told to the
    hazard service (the gate may open without it). False: it was not in the team."""
    robot = next((r for r in await team.robots() if r.name == name), None)
    if robot is None or not await team.remove_robot(name):
        return False
    if robot.kind == RobotKind.WARDEN.value:
        change = TeamChange(robot=name, change=TeamChangeKind.REMOVED, by=by, at=datetime.now(timezone.utc))
        await asyncio.to_thread(tell_hazard_service, admin_url, change)
    return True


def _a(kind: str | None) -> str:
    if kind is None:
        return "a robot of no kind"
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"
