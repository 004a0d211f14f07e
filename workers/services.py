"""The coordination services robots call: hazards and wardens (maps and beacons come later)."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.rpc import Handler, ServiceError
from fleetbus.workers.store.base import LARGEST_INTEGER
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.hazards import (
    CLAIM_WHILE_OPEN,
    DEFAULT_MISSION,
    CoordinationStore,
    Hazard,
    HazardRefused,
)
from fleetbus.workers.team import gate


def _hazard_id(params: dict[str, Any]) -> int:
    value = params.get("hazard_id")
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= LARGEST_INTEGER:
        raise ServiceError(f"hazard_id must be an integer from 1 to {LARGEST_INTEGER}, not {value!r}")
    return value


def hazard_services(hazards: CoordinationStore, channels: ChannelStore) -> dict[str, Handler]:
    async def _mission(caller: str, params: dict[str, Any]) -> str:
        """The mission asked for, else the one the caller is being recorded under, else the default."""
        if params.get("mission_id"):
            return str(params["mission_id"])
        return (await channels.recording_missions([caller])).get(caller, DEFAULT_MISSION)

    async def get(caller: str, params: dict[str, Any]) -> Any:
        """A hazard the caller may look up (:meth:`Hazard.shown_to`): the one it reported, or one
        open to it; a robot sees no more by asking than that."""
        mission, hazard_id = await _mission(caller, params), _hazard_id(params)
        hazard = await hazards.get_hazard(mission, hazard_id)
        if hazard is None:
            raise ServiceError(f"no hazard {hazard_id} in mission {mission!r}")
        if not hazard.shown_to(caller):
            raise ServiceError(
                f"hazard {hazard_id} in mission {mission!r} is not open to {caller} (a robot is "
                "answered only the hazards it reported and those hazard.open gives it)"
            )
        return hazard.as_dict()

    async def open_hazards(caller: str, params: dict[str, Any]) -> Any:
        found = await hazards.open_hazards(await _mission(caller, params))
        return [h.as_dict() for h in found if h.open_to(caller)]

    async def claim_announced(mission: str, hazard_id: int, caller: str, now: datetime) -> Hazard:
        """A claim; of a hazard still held, too, when the gate is open: its announcement reached the
        caller's inbox before the service could mark it announced."""
        try:
            return await hazards.claim(mission, hazard_id, caller, now)
        except HazardRefused:
            if not gate(await hazards.robots(RobotKind.WARDEN.value)).open:
                raise
            return await hazards.apply_transition(mission, hazard_id, caller, CLAIM_WHILE_OPEN, now)

    async def transition(action: str, caller: str, params: dict[str, Any]) -> Any:
        mission, hazard_id, now = (
            await _mission(caller, params),
            _hazard_id(params),
            datetime.now(timezone.utc),
        )
        try:
            if action == "claim":
                hazard = await claim_announced(mission, hazard_id, caller, now)
            elif action == "release":
                hazard = await hazards.release(mission, hazard_id, caller, now)
            elif action == "reached":
                hazard = await hazards.mark_reached(mission, hazard_id, caller, now)
            else:
                hazard = await hazards.mark_cleared(mission, hazard_id, caller, now)
        except HazardRefused as refused:
            raise ServiceError(str(refused)) from None
        return hazard.as_dict()

    async def claim(caller: str, params: dict[str, Any]) -> Any:
        return await transition("claim", caller, params)

    async def release(caller: str, params: dict[str, Any]) -> Any:
        return await transition("release", caller, params)

    async def reached(caller: str, params: dict[str, Any]) -> Any:
        return await transition("reached", caller, params)

    async def cleared(caller: str, params: dict[str, Any]) -> Any:
        return await transition("cleared", caller, params)

    async def wardens(caller: str, params: dict[str, Any]) -> Any:
        return [
            {
                "name": r.name,
                "localised": r.localised,
                "updated_at": r.updated_at.isoformat() if r.updated_at else None,
                "in_service": r.in_service,
            }
            for r in await hazards.robots(RobotKind.WARDEN.value)
        ]

    return {
        "hazard.get": get,
        "hazard.open": open_hazards,
        "hazard.claim": claim,
        "hazard.release": release,
        "hazard.reached": reached,
        "hazard.cleared": cleared,
        "wardens": wardens,
    }
