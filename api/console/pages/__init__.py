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
)

router = APIRouter()
MODULES = (dashboard, alerts, live_map, hazards, missions, messages, dead_letters, evaluation, accounts)
for page in (*MODULES, account):
    router.include_router(page.router)
