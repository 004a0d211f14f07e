"""The console's pages, a module each; ``router`` holds them all."""

from __future__ import annotations

from fastapi import APIRouter

from fleetbus.api.console.pages import dashboard, hazards, missions

router = APIRouter()
for page in (dashboard, hazards, missions):
    router.include_router(page.router)
