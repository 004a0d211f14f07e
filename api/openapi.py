"""What the OpenAPI document says of each operation beyond FastAPI's own: the roles it admits
(``x-roles``) and the refusals it can answer with, each a problem (:mod:`fleetbus.api.problems`).

The refusals are derived from the route, so the document cannot drift from the code:

- a role check among its dependencies: 401 (no valid token) and 403 (a role it does not admit);
- the service among its dependencies: 503 (the store or the broker is unavailable);
- a path parameter: 404 (nothing of that name; also a value with a ``/`` in it, which no route takes);
- a body: 400 (it cannot be read at all: not JSON, or not in its encoding);
- a body, or a parameter whose type not every text fits: 422 (each bad field named).

What only the service knows (a conflict, a name that does not exist outside the path, the
login's limits) the route lists itself with ``responses=refusals(...)``.
"""

from __future__ import annotations

from collections.abc import Iterator
from http import HTTPStatus
from typing import Any

from fastapi import APIRouter, FastAPI
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from pydantic.fields import FieldInfo

from fleetbus.api.auth import RoleCheck, service
from fleetbus.api.problems import PROBLEM_JSON, problem_schemas
from fleetbus.api.services.errors import ServiceRefusal
from fleetbus.schemas.roles import UserRole

#: What each refusal means, as the document says it.
MEANINGS = {
    400: "The body cannot be read: not JSON (or not a form), or not in its encoding",
    401: "Not logged in, or the token has expired, was tampered with, is not ours, or its session has "
    "ended (a logout, a password change, an admin)",
    403: "The caller's role may not do this (an inactive account may do nothing)",
    404: "Not found: the detail says what",
    409: "What is there now does not allow it (the detail says what is)",
    422: "The request is not valid: `errors` names each bad field, or the detail says what the "
    "service refused",
    429: "Too many failed logins: wait for Retry-After seconds",
    503: "The store or the broker is unavailable; try again later",
}
HEADERS: dict[int, dict[str, Any]] = {
    401: {"WWW-Authenticate": {"description": "`Bearer`", "schema": {"type": "string"}}},
    429: {"Retry-After": {"description": "seconds to wait", "schema": {"type": "integer"}}},
}
#: Parameter types every text fits: nothing sent for them can be refused.
ANY_TEXT: frozenset[Any] = frozenset({str, str | None, list[str], list[str] | None})


def refusals(*kinds: int | type[ServiceRefusal]) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: problems with these statuses (or these refusals' statuses)."""
    statuses = {kind if isinstance(kind, int) else kind.status for kind in kinds}
    return {status: _problem_response(status) for status in sorted(statuses)}


def refusal_meaning(status: int, meaning: str) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route whose refusal with ``status`` means more than :data:`MEANINGS` says."""
    return {status: _problem_response(status, meaning)}


def _problem_response(status: int, meaning: str | None = None) -> dict[str, Any]:
    response: dict[str, Any] = {
        "description": meaning or MEANINGS.get(status, HTTPStatus(status).phrase),
        "content": {PROBLEM_JSON: {"schema": {"$ref": "#/components/schemas/Problem"}}},
    }
    if status in HEADERS:
        response["headers"] = HEADERS[status]
    return response


def _dependants(dependant: Dependant) -> Iterator[Dependant]:
    yield dependant
    for sub in dependant.dependencies:
        yield from _dependants(sub)


def _role_checks(dependant: Dependant) -> Iterator[RoleCheck]:
    for each in _dependants(dependant):
        if isinstance(each.call, RoleCheck):
            yield each.call


def route_roles(route: APIRoute) -> list[UserRole]:
    """The roles a route admits (every role check on it must pass)."""
    admitted = set(UserRole)
    for check in _role_checks(route.dependant):
        admitted &= check.roles
    return sorted(admitted, key=list(UserRole).index)


def _refusable(info: FieldInfo, in_path: bool) -> bool:
    """Whether FastAPI can refuse what is sent for a parameter: a type not every text fits, a
    constraint, or (outside the path, where it is always there) a parameter that must be sent."""
    return info.annotation not in ANY_TEXT or bool(info.metadata) or (not in_path and info.is_required())


def derived_refusals(route: APIRoute) -> set[int]:
    """The statuses the route's dependencies and parameters can refuse with (see the module)."""
    dependants = list(_dependants(route.dependant))
    calls = {each.call for each in dependants}
    parameters = [
        (field.field_info, in_path)
        for each in dependants
        for fields, in_path in (
            (each.path_params, True),
            (each.query_params, False),
            (each.header_params, False),
            (each.cookie_params, False),
        )
        for field in fields
    ]
    statuses = set()
    if any(isinstance(call, RoleCheck) for call in calls):
        statuses |= {401, 403}
    if service in calls:
        statuses.add(503)
    if any(each.path_params for each in dependants):
        statuses.add(404)
    has_body = any(each.body_params for each in dependants)
    if has_body:
        statuses.add(400)
    if has_body or any(_refusable(info, in_path) for info, in_path in parameters):
        statuses.add(422)
    return statuses


def document(router: APIRouter) -> APIRouter:
    """Put each route's roles (``x-roles`` and its description) and refusals in the document."""
    for route in router.routes:
        if not isinstance(route, APIRoute) or not route.include_in_schema:
            continue
        if any(True for _ in _role_checks(route.dependant)) and "x-roles" not in (route.openapi_extra or {}):
            roles = [role.value for role in route_roles(route)]
            route.openapi_extra = {**(route.openapi_extra or {}), "x-roles": roles}
            route.description = (route.description or "") + f"\n\nRoles: {', '.join(roles)}."
        responses = {**refusals(*derived_refusals(route)), **route.responses}
        route.responses = dict(sorted(responses.items(), key=lambda item: str(item[0])))
    return router


def with_problem_schemas(app: FastAPI) -> None:
    """The Problem schema in the document's components, once, for every refusal to refer to; and
    without the 422 FastAPI lists by itself on every route with parameters, where
    :func:`derived_refusals` found none (a route that can refuse them lists its own 422)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            document = build()  # FastAPI keeps it as app.openapi_schema
            for operations in document["paths"].values():
                for operation in operations.values():
                    automatic = operation["responses"].get("422")
                    if automatic is not None and PROBLEM_JSON not in automatic.get("content", {}):
                        del operation["responses"]["422"]
            schemas = document.setdefault("components", {}).setdefault("schemas", {})
            for unused in ("HTTPValidationError", "ValidationError"):
                schemas.pop(unused, None)
            schemas.update(problem_schemas())
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
