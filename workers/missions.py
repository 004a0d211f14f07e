"""Stamp each event with the mission its robot is being recorded under.

A robot's data is recorded under a mission while the operator who mounted it for that mission
is checked in (see ``workers.store.channels``). The stamp is taken when the worker records the
event and is stored with it; the store never rewrites it (a redelivery keeps the first record).
The hazard service then numbers the hazard within that mission.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from workers.store.channels import ChannelStore
from workers.validation import Accepted


class MissionStamp:
    def __init__(self, store: ChannelStore) -> None:
        self._store = store

    async def enrich(self, accepted: Sequence[Accepted]) -> list[Accepted]:
        missions = await self._store.recording_missions({item.record.robot_id for item in accepted})
        return [
            Accepted(item.event, replace(item.record, mission_id=missions[item.record.robot_id]))
            if item.record.robot_id in missions
            else item
            for item in accepted
        ]
