"""Missions: created by clients, planned, then moved through their use case's state machine.

Every change is checked against the machine (the step exists from the current state, the
caller's role may take it, the plan is ready for it) and then written as a compare-and-set on
the state the check saw; when another change got in first, the caller is told the state it left.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from datetime import datetime, timezone

from fleetbus.api.services.errors import BadRequest, Conflict, Forbidden, NotFound
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.use_cases import STEPS, InvalidTransition, RoleNotAllowed, machine_for, readiness
from fleetbus.workers.store.channels import ChannelStore, CheckIn, Mount
from fleetbus.workers.store.missions import Mission, MissionConflict, MissionStore, StateChange
from fleetbus.workers.store.users import User

#: Who sees every mission; a client sees its own.
SEE_ALL = frozenset(
    {UserRole.ADMIN, UserRole.PLANNER, UserRole.SUPERVISOR, UserRole.OPERATOR, UserRole.GUEST}
)
#: Who creates missions and edits their plans.
AUTHORS = frozenset({UserRole.CLIENT, UserRole.PLANNER})
#: Who may ask for a step at all: every role some step admits (the machine says which step).
MOVERS = frozenset(role for step in STEPS.values() for role in step.roles)
SERVICE_ACTOR = "fleetbus"
#: The longest title a mission may have (the HTTP API, the console and the command line alike).
TITLE_MOST = 200

log = logging.getLogger("fleetbus.api")


def use_case_refusal(user: User, use_case: str) -> str | None:
    """Why ``user`` may not create a mission of ``use_case`` (None: it may): the one rule for the
    HTTP API, the command line and the console. An account none were set for may use every one."""
    if user.use_cases is None or use_case in user.use_cases:
        return None
    allowed = ", ".join(user.use_cases) or "none"
    return (
        f"{user.name} may not create {use_case!r} missions; its use cases: {allowed} "
        f"(an admin changes them: `fleetbus users use-cases {user.name} --allow ...`)"
    )


@dataclass(frozen=True)
class MissionDetail:
    """A mission as its page shows it: the robots mounted for it, the operators checked in, and
    every state it went through (oldest first)."""

    mission: Mission
    mounts: list[Mount]
    check_ins: list[CheckIn]
    history: list[StateChange]


def may_see(user: User, owner: str) -> bool:
    """Whether ``user`` sees a mission of ``owner``'s (as :meth:`Missions.get` admits it)."""
    return user.role in SEE_ALL or owner == user.name


#: Told each mission as it is after a change (central sends it to its sites).
MissionListener = Callable[[Mission], Awaitable[object]]


@dataclass(frozen=True)
class MyMission:
    """A mission on a user's dashboard, and why it is there."""

    mission: Mission
    why: str


class Missions:
    def __init__(
        self, missions: MissionStore, channels: ChannelStore, on_change: MissionListener | None = None
    ) -> None:
        self._missions = missions
        self._channels = channels
        self._on_change = on_change

    async def _changed(self, mission: Mission) -> Mission:
        if self._on_change is not None:
            try:
                await self._on_change(mission)
            except Exception:  # the change is made; `fleetbus sites sync` sends the sites it again
                log.exception(
                    "mission %s changed but not sent to the sites: run `fleetbus sites sync`",
                    mission.mission_id,
                )
        return mission

    async def create(self, user: User, use_case: str, title: str, plan: MissionPlan) -> Mission:
        """A new mission of ``user``'s, in planning, its title stripped; refused to a role that does
        not create missions, for a use case the user is not allowed (:func:`use_case_refusal`), and
        for a title blank or longer than :data:`TITLE_MOST`."""
        if user.role not in AUTHORS:
            who = " or ".join(sorted(role.value for role in AUTHORS))
            raise Forbidden(f"{user.name} is {user.role.value}: missions are created by a {who}")
        try:
            machine_for(use_case)
        except InvalidTransition as error:
            raise BadRequest(str(error)) from None
        if refusal := use_case_refusal(user, use_case):
            raise Forbidden(refusal)
        title = title.strip()
        if not 1 <= len(title) <= TITLE_MOST:
            raise BadRequest(f"title: a mission's title has 1 to {TITLE_MOST} characters, not {len(title)}")
        created = await self._missions.create_mission(
            use_case, title, user.name, plan.model_dump(mode="json"), datetime.now(timezone.utc)
        )
        return await self._changed(created)

    async def get(self, user: User, mission_id: str) -> Mission:
        mission = await self._missions.get_mission(mission_id)
        if mission is None:
            raise NotFound(f"no mission {mission_id!r}")
        if user.role not in SEE_ALL and mission.owner != user.name:
            raise Forbidden(f"mission {mission_id} belongs to another client")
        return mission

    async def detail(self, user: User, mission_id: str) -> MissionDetail:
        """The mission, if ``user`` may see it (:meth:`get`), with its mounts, check-ins and history."""
        mission = await self.get(user, mission_id)
        return MissionDetail(
            mission,
            await self._channels.mounts(mission_id=mission_id),
            await self._channels.check_ins(mission_id=mission_id),
            await self._missions.mission_history(mission_id),
        )

    async def every(self) -> list[Mission]:
        """Every mission, in creation order, for a view shared by its users, each of whom is shown
        those :func:`may_see` admits."""
        return await self._missions.missions()

    async def active_for(self, user: User) -> list[MyMission]:
        """The missions not yet closed that are ``user``'s work, by number: those it owns, those it
        mounted robots for or is checked in to, and those waiting for a step its role may take (a
        client's own only, as it sees no other)."""
        mine: dict[str, list[str]] = {}
        for mount in await self._channels.mounts(operator=user.name):
            mine.setdefault(mount.mission_id, []).append(f"you mounted {mount.robot}")
        for check_in in await self._channels.check_ins(operator=user.name):
            mine.setdefault(check_in.mission_id, []).append("you are checked in")
        owner = None if user.role in SEE_ALL else user.name
        candidates = [
            mission
            for state in MissionState
            if state is not MissionState.CLOSED
            for mission in await self._missions.missions(owner=owner, state=state)
        ]
        found = []
        for mission in sorted(candidates, key=lambda m: m.number):
            why = list(mine.get(mission.mission_id, []))
            if mission.owner == user.name:
                why.insert(0, "yours")
            steps = machine_for(mission.use_case).steps_from(mission.state)
            if waiting := [step.target.value for step in steps if user.role in step.roles]:
                why.append(f"next for you: {', '.join(waiting)}")
            if why:
                found.append(MyMission(mission, "; ".join(why)))
        return found

    async def get_any(self, mission_id: str) -> Mission:
        mission = await self._missions.get_mission(mission_id)
        if mission is None:
            raise NotFound(f"no mission {mission_id!r}")
        return mission

    async def visible(self, user: User, state: MissionState | None = None) -> list[Mission]:
        owner = None if user.role in SEE_ALL else user.name
        return await self._missions.missions(owner=owner, state=state)

    async def edit_plan(self, user: User, mission_id: str, plan: MissionPlan) -> Mission:
        mission = await self.get(user, mission_id)
        if user.role is UserRole.CLIENT and mission.owner != user.name:
            raise Forbidden(f"mission {mission_id} belongs to another client")
        try:
            edited = await self._missions.update_plan(
                mission_id, plan.model_dump(mode="json"), MissionState.PLANNING, datetime.now(timezone.utc)
            )
        except MissionConflict as conflict:
            state = conflict.current.state.value if conflict.current else "gone"
            raise Conflict(f"mission {mission_id} is {state}: its plan can change only in planning") from None
        return await self._changed(edited)

    async def transition(
        self, user: User | None, mission_id: str, target: MissionState, note: str = ""
    ) -> Mission:
        """Take one step; ``user`` ``None`` is the service itself (the last operator checked out)."""
        mission = await self._missions.get_mission(mission_id)
        if mission is None:
            raise NotFound(f"no mission {mission_id!r}")
        if user is not None and user.role is UserRole.CLIENT and mission.owner != user.name:
            raise Forbidden(f"mission {mission_id} belongs to another client")
        machine = machine_for(mission.use_case)
        try:
            machine.step(mission.state, target, user.role if user else None)
        except RoleNotAllowed as error:
            raise Forbidden(f"mission {mission_id}: {error}") from None
        except InvalidTransition as error:
            raise Conflict(f"mission {mission_id}: {error}") from None
        missing = readiness(MissionPlan.model_validate(mission.plan), target)
        if missing:
            raise Conflict(f"mission {mission_id} cannot become {target.value}: {'; '.join(missing)}")
        if target is MissionState.CLOSED:
            mounted = await self._channels.mounts(mission_id=mission_id)
            if mounted:
                robots = ", ".join(f"{m.robot} (by {m.operator})" for m in mounted)
                raise Conflict(f"mission {mission_id} still has robots mounted: {robots}; unmount them first")
        try:
            moved = await self._missions.transition_mission(
                mission_id,
                mission.state,
                target,
                user.name if user else SERVICE_ACTOR,
                datetime.now(timezone.utc),
                note,
            )
        except MissionConflict as conflict:
            now = conflict.current.state if conflict.current else mission.state
            allowed = ", ".join(t.value for t in machine.allowed_targets(now)) or "none"
            raise Conflict(
                f"mission {mission_id} changed meanwhile: it is now {now.value} "
                f"(not {mission.state.value}); allowed next: {allowed}"
            ) from None
        return await self._changed(moved)
