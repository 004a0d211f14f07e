"""The fleetbus HTTP API: users and roles, missions, mounts and check-ins (FastAPI).

``create_app`` builds the app for one broker (as administrator) and the settings' store; the
``fleetbus api`` command serves it with uvicorn. The OpenAPI document is at ``/openapi.json``
(and ``/docs``); each operation lists the roles it admits under ``x-roles``.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException, Request
from fastapi.dependencies.models import Dependant
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi.routing import APIRoute

from fleetbus.api import audit
from fleetbus.api.auth import RoleCheck
from fleetbus.api.console.feed import running_feed
from fleetbus.api.console.router import install_console
from fleetbus.api.errors import ServiceRefusal
from fleetbus.api.routes import auth, beacons, channels, hazards, missions, recording, team, users
from fleetbus.api.service import open_service
from fleetbus.broker.certificates import TlsFiles
from fleetbus.schemas.roles import UserRole
from fleetbus.settings import Settings
from fleetbus.workers.store.base import StoreUnavailable


def _role_checks(dependant: Dependant) -> Iterator[RoleCheck]:
    for sub in dependant.dependencies:
        if isinstance(sub.call, RoleCheck):
            yield sub.call
        yield from _role_checks(sub)


def route_roles(route: APIRoute) -> list[UserRole]:
    """The roles a route admits (every role check on it must pass)."""
    admitted = set(UserRole)
    for check in _role_checks(route.dependant):
        admitted &= check.roles
    return sorted(admitted, key=list(UserRole).index)


def document_roles(router: APIRouter) -> APIRouter:
    """Put each route's roles in its OpenAPI operation (``x-roles``) and description."""
    for route in router.routes:
        already = isinstance(route, APIRoute) and "x-roles" in (route.openapi_extra or {})
        if isinstance(route, APIRoute) and not already and any(True for _ in _role_checks(route.dependant)):
            roles = route_roles(route)
            route.openapi_extra = {**(route.openapi_extra or {}), "x-roles": [r.value for r in roles]}
            route.description = (route.description or "") + f"\n\nRoles: {', '.join(r.value for r in roles)}."
    return router


def create_app(
    settings: Settings, admin_url: str, management_url: str, public_url: str | None = None
) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with open_service(settings, admin_url, management_url, public_url) as service:
            app.state.service = service
            async with running_feed(service.repositories.events, settings) as feed:
                app.state.feed = feed
                yield

    app = FastAPI(
        title="fleetbus service layer",
        version="0.1.0",
        description="Accounts and roles, missions and their state machines, mount and check-in of "
        "robots. Log in at POST /auth/token; send the token as 'Authorization: Bearer <token>'.",
        lifespan=lifespan,
    )
    for router in (
        auth.router,
        users.router,
        missions.router,
        channels.router,
        beacons.router,
        recording.router,
        team.router,
        hazards.router,
    ):
        app.include_router(document_roles(router))

    install_console(app)

    @app.get("/ca.pem", tags=["health"], response_class=PlainTextResponse)
    async def ca_certificate() -> PlainTextResponse:
        """The CA certificate (PEM) robots and clients verify the broker and this API with: public,
        no login needed (``FLEETBUS_TLS_CA``, else the one ``fleetbus certs make`` made)."""
        path = TlsFiles.for_settings(settings).ca
        if not path.exists():
            raise HTTPException(404, detail=f"no CA certificate here ({path}): run `fleetbus certs make`")
        return PlainTextResponse(path.read_text(), media_type="application/x-pem-file")

    @app.get("/health", tags=["health"])
    async def health() -> dict[str, Any]:
        return {"ok": True, "store": app.state.service.repositories.name}

    @app.exception_handler(ServiceRefusal)
    async def refusal(request: Request, error: ServiceRefusal) -> JSONResponse:
        if error.status == 403:
            user = getattr(request.state, "user", None)
            audit.refused(request, 403, f"{user.name} ({user.role.value})" if user else "?", error.detail)
        return JSONResponse({"detail": error.detail}, status_code=error.status)

    @app.exception_handler(StoreUnavailable)
    async def store_down(request: Request, error: StoreUnavailable) -> JSONResponse:
        return JSONResponse({"detail": f"the store is unavailable: {error}"}, status_code=503)

    return app
