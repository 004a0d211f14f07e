"""Missions and their state history.

A state change is a compare-and-set in the store: it names the state it expects to leave, so of
two concurrent changes from the same state exactly one wins and the other learns the state the
winner left behind. Plans can change only while the mission is in planning, checked the same way.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fleetbus.schemas.mission_states import MissionState
from fleetbus.workers.store.base import StoreError

MISSION_PREFIX = "m-"


def mission_id_of(number: int) -> str:
    return f"{MISSION_PREFIX}{number}"


@dataclass(frozen=True)
class Mission:
    mission_id: str
    number: int
    use_case: str
    title: str
    owner: str
    """The client who requested it."""
    state: MissionState
    plan: dict[str, Any]
    """A :class:`fleetbus.schemas.missions.MissionPlan` as JSON."""
    created_at: datetime
    updated_at: datetime


@dataclass(frozen=True)
class StateChange:
    mission_id: str
    source: MissionState | None
    """``None`` for the creation."""
    target: MissionState
    by: str
    at: datetime
    note: str = ""


class MissionConflict(StoreError):
    """The mission is not in the state the change expected (or does not exist)."""

    def __init__(self, mission_id: str, current: Mission | None) -> None:
        self.current = current
        state = current.state.value if current else None
        super().__init__(
            f"no mission {mission_id!r}" if current is None else f"mission {mission_id} is {state}"
        )


class MissionStore(abc.ABC):
    @abc.abstractmethod
    async def create_mission(
        self, use_case: str, title: str, owner: str, plan: dict[str, Any], at: datetime
    ) -> Mission:
        """A new mission in planning, with the next number (``m-1``, ``m-2``...)."""

    @abc.abstractmethod
    async def get_mission(self, mission_id: str) -> Mission | None: ...

    @abc.abstractmethod
    async def missions(self, owner: str | None = None, state: MissionState | None = None) -> list[Mission]:
        """Missions in creation order."""

    @abc.abstractmethod
    async def update_plan(
        self, mission_id: str, plan: dict[str, Any], expected: MissionState, at: datetime
    ) -> Mission:
        """Replace the plan if the mission is in ``expected``; else raise :class:`MissionConflict`."""

    @abc.abstractmethod
    async def transition_mission(
        self,
        mission_id: str,
        source: MissionState,
        target: MissionState,
        by: str,
        at: datetime,
        note: str = "",
    ) -> Mission:
        """Move from ``source`` to ``target`` atomically and record it; else :class:`MissionConflict`."""

    @abc.abstractmethod
    async def put_mission(self, mission: Mission) -> bool:
        """Keep ``mission`` as another store (central's) has it, unless this store has a version
        as new or newer (by ``updated_at``); whether it was written. Its history here records
        the state it arrived in."""

    @abc.abstractmethod
    async def mission_history(self, mission_id: str) -> list[StateChange]:
        """Every state the mission went through, oldest first."""
