"""The console's pages, a module each; ``router`` holds them all."""

from __future__ import annotations

from fastapi import APIRouter

from fleetbus.api.console.pages import accounts, dashboard, dead_letters, hazards, missions

router = APIRouter()
for page in (dashboard, hazards, missions, dead_letters, accounts):
    router.include_router(page.router)
