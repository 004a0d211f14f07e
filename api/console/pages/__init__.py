"""The console's pages, a module each; ``router`` holds them all."""

from __future__ import annotations

from fastapi import APIRouter

from fleetbus.api.console.pages import dashboard, live_map

router = APIRouter()
for page in (dashboard, live_map):
    router.include_router(page.router)
