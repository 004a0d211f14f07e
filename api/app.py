"""The fleetbus HTTP API: users and roles, missions, mounts and check-ins (FastAPI).

``create_app`` builds the app for one broker (as administrator) and the settings' store; the
``fleetbus api`` command serves it with uvicorn. The OpenAPI document is at ``/openapi.json``
(and ``/docs``); each operation lists the roles it admits under ``x-roles`` and the refusals it
can answer with, every one an RFC 9457 problem (:mod:`fleetbus.api.openapi`,
:mod:`fleetbus.api.problems`).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, HTTPException
from fastapi.responses import PlainTextResponse

from fleetbus.api.console.feed import running_feed
from fleetbus.api.console.router import install_console
from fleetbus.api.openapi import document, refusals, with_problem_schemas
from fleetbus.api.problems import install_problem_handlers
from fleetbus.api.routes import (
    alerts,
    auth,
    beacons,
    channels,
    hazards,
    mission_comments,
    missions,
    recording,
    team,
    users,
)
from fleetbus.api.service import open_service
from fleetbus.broker.certificates import TlsFiles
from fleetbus.settings import Settings


def create_app(
    settings: Settings, admin_url: str, management_url: str, public_url: str | None = None
) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with open_service(settings, admin_url, management_url, public_url) as service:
            app.state.service = service
            async with running_feed(service.events, settings) as feed:
                app.state.feed = feed
                yield

    app = FastAPI(
        title="fleetbus service layer",
        version="0.1.0",
        description="Accounts and roles, missions and their state machines, mount and check-in of "
        "robots. Log in at POST /auth/token; send the token as 'Authorization: Bearer <token>'. "
        "Every refusal is an RFC 9457 problem (application/problem+json, the Problem schema): "
        "type, title, status, detail (what went wrong, in words) and instance (the request's "
        "path); a request that is not valid also gets errors, each bad field with its location "
        "(loc), what is wrong (msg) and its kind (type).",
        lifespan=lifespan,
        # each operation's id is its function's name: what a generated client calls it
        generate_unique_id_function=lambda route: route.name,
    )
    for router in (
        auth.router,
        users.router,
        missions.router,
        mission_comments.router,
        channels.router,
        beacons.router,
        recording.router,
        team.router,
        hazards.router,
        alerts.router,
    ):
        app.include_router(document(router))

    install_console(app)

    @app.get(
        "/ca.pem",
        tags=["health"],
        response_class=PlainTextResponse,
        responses=refusals(404),
    )
    async def ca_certificate() -> PlainTextResponse:
        """The CA certificate (PEM, a text: ``text/plain``) robots and clients verify the broker and
        this API with: public, no login needed (``FLEETBUS_TLS_CA``, else the one ``fleetbus certs
        make`` made)."""
        path = TlsFiles.for_settings(settings).ca
        if not path.exists():
            raise HTTPException(404, detail=f"no CA certificate here ({path}): run `fleetbus certs make`")
        return PlainTextResponse(path.read_text())

    @app.get("/health", tags=["health"])
    async def health() -> dict[str, Any]:
        return {"ok": True, "store": app.state.service.repositories.name}

    document(app.router)
    install_problem_handlers(app)
    with_problem_schemas(app)
    return app
