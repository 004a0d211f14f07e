"""Tell the store which robots form the team, and of which kind (the hazard gate counts wardens)."""

from __future__ import annotations

from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import Settings
from fleetbus.workers.store import Repositories, run_with_repositories


def register_robot(settings: Settings, name: str, kind: RobotKind | None) -> None:
    run_with_repositories(
        settings, lambda repos: repos.hazards.register_robot(name, kind.value if kind else None)
    )


def register_robots(settings: Settings, robots: list[tuple[str, RobotKind | None]]) -> None:
    """Many robots, over one connection to the store."""

    async def register(repos: Repositories) -> None:
        for name, kind in robots:
            await repos.hazards.register_robot(name, kind.value if kind else None)

    run_with_repositories(settings, register)
