"""Channel changes, made by the service only: mount, unmount, check-in, check-out.

A mount is booked in the store first (atomic: of two operators, one gets the robot), then its
bindings are made on the broker; if the broker fails, the booking is undone. An unmount removes
the booking first, then the bindings. Either way a crash in between leaves the broker with more
or fewer bindings than the store says, which :meth:`Channels.verify` reports and
:meth:`Channels.repair` fixes by making the broker follow the store. Every change is recorded.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from datetime import datetime, timezone

from fleetbus.api.services.errors import Conflict, Forbidden, NotFound, Unavailable
from fleetbus.api.services.missions import Missions
from fleetbus.broker.management import ManagementAPI, ManagementError
from fleetbus.broker.mounts import (
    QueueBinding,
    bind_all,
    mount_bindings,
    mount_bindings_on_broker,
    unbind_all,
)
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.use_cases import CHECK_IN_STATES, InvalidTransition, machine_for
from fleetbus.workers.store.channels import Booked, ChannelAction, ChannelChange, ChannelStore, CheckIn, Mount
from fleetbus.workers.store.missions import Mission
from fleetbus.workers.store.users import User, UserStore

log = logging.getLogger("fleetbus.api.channels")

#: Who mounts robots, and checks in to missions and out.
OPERATING = frozenset({UserRole.OPERATOR})
#: Who unmounts: an operator its own robots, a supervisor anyone's (a forced unmount).
UNMOUNTERS = frozenset({UserRole.OPERATOR, UserRole.SUPERVISOR})


def may_unmount(user: User, mount: Mount) -> bool:
    """Whether ``user`` may unmount ``mount``'s robot: the operator who mounted it, or a supervisor."""
    return user.role is UserRole.SUPERVISOR or (user.role in UNMOUNTERS and mount.operator == user.name)


@dataclass(frozen=True)
class BindingReport:
    expected: list[QueueBinding]
    actual: list[QueueBinding]

    @property
    def missing(self) -> list[QueueBinding]:
        return sorted(set(self.expected) - set(self.actual))

    @property
    def unexpected(self) -> list[QueueBinding]:
        return sorted(set(self.actual) - set(self.expected))

    @property
    def consistent(self) -> bool:
        return not self.missing and not self.unexpected


@dataclass(frozen=True)
class CheckOut:
    operator: str
    mission: Mission
    operators_left: int


class Channels:
    def __init__(
        self,
        channels: ChannelStore,
        users: UserStore,
        management: ManagementAPI,
        vhost: str,
        missions: Missions,
    ) -> None:
        self._channels = channels
        self._users = users
        self._management = management
        self._vhost = vhost
        self._missions = missions
        # one channel change at a time in this process, so store and broker change in the same order
        self._lock = asyncio.Lock()

    async def _record(
        self,
        actor: User,
        action: ChannelAction,
        mission_id: str | None,
        operator: str | None,
        robot: str | None,
        detail: str = "",
    ) -> None:
        change = ChannelChange(
            datetime.now(timezone.utc), actor.name, action, mission_id, operator, robot, detail
        )
        await self._channels.record_change(change)
        log.info(
            "%s by %s: robot %s, operator %s, mission %s %s",
            action.value,
            actor.name,
            robot,
            operator,
            mission_id,
            detail,
        )

    async def _broker(self, work: str, bindings: tuple[QueueBinding, ...], bind: bool) -> None:
        try:
            await asyncio.to_thread(bind_all if bind else unbind_all, self._management, self._vhost, bindings)
        except (ManagementError, OSError) as error:
            raise Unavailable(f"the broker failed to {work}: {error}") from error

    async def mounts(
        self, operator: str | None = None, mission_id: str | None = None, robot: str | None = None
    ) -> list[Mount]:
        """The robots mounted now, by robot (an operator's, a mission's or a robot's if given)."""
        return await self._channels.mounts(operator=operator, mission_id=mission_id, robot=robot)

    async def check_ins(self, mission_id: str | None = None, operator: str | None = None) -> list[CheckIn]:
        """The operators checked in now, by operator (to a mission, or one operator's, if given)."""
        return await self._channels.check_ins(mission_id=mission_id, operator=operator)

    async def mountable(self) -> tuple[int, list[str]]:
        """How many robots the team has, and those an operator can mount: the robots not mounted
        for any mission (a robot is mounted for one mission at a time)."""
        booked = {m.robot for m in await self._channels.mounts()}
        robots = await self._users.users(UserRole.ROBOT)
        return len(robots), [robot.name for robot in robots if robot.name not in booked]

    async def changes(self, mission_id: str | None = None, limit: int | None = None) -> list[ChannelChange]:
        """Every mount, unmount, check-in and check-out recorded (of a mission, if given), oldest
        first (the newest ``limit`` when given)."""
        return await self._channels.channel_changes(mission_id, limit)

    async def mount(self, operator: User, robot: str, mission_id: str) -> Mount:
        target = await self._users.get_user(robot)
        if target is None or target.role is not UserRole.ROBOT:
            raise NotFound(f"no robot {robot!r}")
        mission = await self._missions.get(operator, mission_id)
        machine = machine_for(mission.use_case)
        if not machine.mountable(mission.state):
            states = ", ".join(s.value for s in machine.states if machine.mountable(s))
            raise Conflict(
                f"mission {mission_id} is {mission.state.value}; robots can be mounted when it is {states}"
            )
        async with self._lock:
            try:
                mount = await self._channels.mount(
                    robot, operator.name, mission_id, datetime.now(timezone.utc)
                )
            except Booked as booked:
                raise Conflict(str(booked)) from None
            try:
                await self._broker(f"mount {robot}", mount_bindings(robot, operator.name), bind=True)
            except Unavailable:
                await self._channels.unmount(robot, operator.name)
                raise
            await self._record(operator, ChannelAction.MOUNT, mission_id, operator.name, robot)
        return mount

    async def unmount(self, user: User, robot: str) -> Mount:
        """An operator unmounts its own robot; a supervisor may unmount anyone's (a forced unmount)."""
        current = await self._channels.mounts(robot=robot)
        if not current:
            raise NotFound(f"robot {robot} is not mounted")
        force = user.role is UserRole.SUPERVISOR
        if not may_unmount(user, current[0]):
            raise Forbidden(
                f"robot {robot} is mounted by {current[0].operator}; only they or a supervisor can unmount it"
            )
        async with self._lock:
            removed = await self._channels.unmount(robot, None if force else user.name)
            if removed is None:
                raise NotFound(f"robot {robot} is not mounted")
            await self._broker(f"unmount {robot}", mount_bindings(robot, removed.operator), bind=False)
            action = ChannelAction.FORCE_UNMOUNT if force else ChannelAction.UNMOUNT
            await self._record(user, action, removed.mission_id, removed.operator, robot)
        return removed

    async def check_in(self, operator: User, mission_id: str) -> CheckIn:
        mission = await self._missions.get(operator, mission_id)
        if mission.state not in CHECK_IN_STATES:
            raise Conflict(
                f"mission {mission_id} is {mission.state.value}; operators check in while it is in_progress"
            )
        try:
            check_in = await self._channels.check_in(operator.name, mission_id, datetime.now(timezone.utc))
        except Booked as booked:
            raise Conflict(str(booked)) from None
        robots = [m.robot for m in await self._channels.mounts(operator=operator.name, mission_id=mission_id)]
        await self._record(
            operator, ChannelAction.CHECK_IN, mission_id, operator.name, None, f"recording {robots}"
        )
        return check_in

    async def check_out(self, operator: User, mission_id: str) -> CheckOut:
        mission = await self._missions.get(operator, mission_id)
        if not await self._channels.check_out(operator.name, mission_id):
            raise Conflict(f"{operator.name} is not checked in to mission {mission_id}")
        await self._record(operator, ChannelAction.CHECK_OUT, mission_id, operator.name, None)
        left = await self._channels.check_ins(mission_id=mission_id)
        if not left:
            mission = await self._end_operations(mission)
        return CheckOut(operator.name, mission, len(left))

    async def _end_operations(self, mission: Mission) -> Mission:
        """The last operator checked out: the mission moves to reviewing, if its machine allows it now."""
        try:
            machine_for(mission.use_case).step(mission.state, MissionState.REVIEWING, None)
        except InvalidTransition:
            return mission
        try:
            return await self._missions.transition(
                None, mission.mission_id, MissionState.REVIEWING, "every operator checked out"
            )
        except Conflict:  # someone else changed the state meanwhile; theirs stands
            return await self._missions.get_any(mission.mission_id)

    async def verify(self) -> BindingReport:
        expected = [b for m in await self._channels.mounts() for b in mount_bindings(m.robot, m.operator)]
        actual = await asyncio.to_thread(mount_bindings_on_broker, self._management, self._vhost)
        return BindingReport(sorted(expected), sorted(actual))

    async def repair(self, user: User) -> BindingReport:
        """Make the broker's mount bindings what the store says, and record what was changed."""
        async with self._lock:
            report = await self.verify()
            if report.consistent:
                return report
            await self._broker("add missing bindings", tuple(report.missing), bind=True)
            await self._broker("remove unexpected bindings", tuple(report.unexpected), bind=False)
            detail = (
                f"added {[str(b) for b in report.missing]}, removed {[str(b) for b in report.unexpected]}"
            )
            await self._record(user, ChannelAction.REPAIR, None, None, None, detail)
        return await self.verify()
