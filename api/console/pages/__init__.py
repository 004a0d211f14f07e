"""The console's pages, a module each; ``router`` holds them all."""

from __future__ import annotations

from fastapi import APIRouter

from fleetbus.api.console.pages import dashboard, evaluation, messages

router = APIRouter()
for page in (dashboard, messages, evaluation):
    router.include_router(page.router)
