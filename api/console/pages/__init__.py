"""The console's pages, a module each; ``router`` holds them all."""

from __future__ import annotations

from fastapi import APIRouter

from fleetbus.api.console.pages import (
    account,
    accounts,
    alerts,
    dashboard,
    dead_letters,
    evaluation,
    hazards,
    live_map,
    messages,
    missions,
    new_mission,
)

router = APIRouter()
# new_mission before missions: its /console/missions/new is no mission id
for page in (
    dashboard,
    alerts,
    live_map,
    hazards,
    new_mission,
    missions,
    messages,
    dead_letters,
    evaluation,
    accounts,
    account,
):
    router.include_router(page.router)
