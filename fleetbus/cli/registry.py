"""Tell the store which robots form the team, and of which kind (the hazard gate counts wardens)."""

from __future__ import annotations

from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import Settings
from fleetbus.workers.store import run_with_repositories


def register_robot(settings: Settings, name: str, kind: RobotKind | None) -> None:
    run_with_repositories(
        settings, lambda repos: repos.hazards.register_robot(name, kind.value if kind else None)
    )
