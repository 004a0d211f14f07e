"""Hazard steps an operator takes for a warden, as the service layer offers them
(:mod:`fleetbus.workers.hazard_steps`): refusals become the service's own answers."""

from __future__ import annotations

from fleetbus.api.services.errors import Conflict
from fleetbus.workers.hazard_steps import StepRefused, StepTaken, take_step
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.hazards import CoordinationStore


class HazardSteps:
    def __init__(self, hazards: CoordinationStore, channels: ChannelStore, admin_url: str) -> None:
        self._hazards = hazards
        self._channels = channels
        self._admin_url = admin_url

    async def take(self, mission_id: str, hazard_id: int, warden: str, step: str, by: str) -> StepTaken:
        """Take ``step`` for ``warden`` and tell it; :class:`Conflict` when the step is refused."""
        try:
            return await take_step(
                self._hazards, self._channels, self._admin_url, mission_id, hazard_id, warden, step, by
            )
        except StepRefused as refused:
            raise Conflict(str(refused)) from None
