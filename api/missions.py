"""Missions: created by clients, planned, then moved through their use case's state machine.

Every change is checked against the machine (the step exists from the current state, the
caller's role may take it, the plan is ready for it) and then written as a compare-and-set on
the state the check saw; when another change got in first, the caller is told the state it left.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from datetime import datetime, timezone

from fleetbus.api.errors import BadRequest, Conflict, Forbidden, NotFound
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.use_cases import STEPS, InvalidTransition, RoleNotAllowed, machine_for, readiness
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.missions import Mission, MissionConflict, MissionStore
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

log = logging.getLogger("fleetbus.api")

#: Told each mission as it is after a change (central sends it to its sites).
MissionListener = Callable[[Mission], Awaitable[object]]


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
        try:
            machine_for(use_case)
        except InvalidTransition as error:
            raise BadRequest(str(error)) from None
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
