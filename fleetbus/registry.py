"""Tell the store which robots form the team, and of which kind (the hazard gate counts wardens)."""

from __future__ import annotations

import asyncio

from fleetbus.config import Settings
from schemas.routing import RobotKind
from workers.store import open_store


def register_robot(settings: Settings, name: str, kind: RobotKind | None) -> None:
    async def go() -> None:
        async with open_store(settings) as store:
            await store.register_robot(name, kind.value if kind else None)

    asyncio.run(go())
