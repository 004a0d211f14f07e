"""Every refusal of the HTTP API as RFC 9457 problem details (``application/problem+json``), made
here and nowhere else: the service's own refusals (:class:`~fleetbus.api.services.errors.ServiceRefusal`),
FastAPI's and Starlette's ``HTTPException`` (401 with ``WWW-Authenticate``, 429 with
``Retry-After``: their headers are kept), request validation (422, each bad field in ``errors``
with its location) and an unavailable store (503).

    {"type": "about:blank", "title": "Forbidden", "status": 403,
     "detail": "role guest may not do this; it needs admin", "instance": "/users"}

``detail`` is the sentence the command line prints for the same refusal. No library is used:
fastapi-problem answers every unhandled exception itself and lists a blanket 4XX and 5XX on every
operation, fastapi-problem-details a ``default`` response; fastapi-rfc9457 is weeks old. The
statuses each operation lists are derived from the route (:mod:`fleetbus.api.refusals`), which none
of them does; what is left is the few lines below.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from http import HTTPStatus
from typing import Any

import httpx
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import Response
from pydantic import BaseModel, Field
from pydantic.json_schema import SkipJsonSchema
from starlette.exceptions import HTTPException

from fleetbus.api import audit
from fleetbus.api.services.errors import ServiceRefusal, unavailable
from fleetbus.broker.management import ManagementError
from fleetbus.workers.store.base import StoreUnavailable

PROBLEM_JSON = "application/problem+json"


class FieldProblem(BaseModel):
    """One bad value of a request, where it is and what is wrong with it."""

    loc: list[str | int] = Field(
        description="where: `body`, `query`, `path` or `header`, then the field's path within it"
    )
    msg: str = Field(description="what is wrong with it")
    type: str = Field(description="the kind of error (pydantic's error type, e.g. `greater_than_equal`)")


class Problem(BaseModel):
    """A refusal, as RFC 9457 problem details."""

    type: str = Field("about:blank", description="`about:blank`: the status says what kind of problem")
    title: str = Field(description="the status's phrase, e.g. `Forbidden`")
    status: int = Field(description="the HTTP status")
    detail: str = Field(description="what went wrong, for a person to read")
    instance: str = Field(description="the path of the request refused")
    errors: list[FieldProblem] | SkipJsonSchema[None] = Field(
        None,
        description="validation errors only: each bad field of the request",
        json_schema_extra=lambda schema: schema.pop("default", None),
    )


def problem_response(
    request: Request,
    status: int,
    detail: str,
    headers: Mapping[str, str] | None = None,
    errors: Sequence[FieldProblem] | None = None,
) -> Response:
    problem = Problem(
        title=HTTPStatus(status).phrase,
        status=status,
        detail=detail,
        instance=request.url.path,
        errors=list(errors) if errors is not None else None,
    )
    body = problem.model_dump_json(exclude_none=True)
    return Response(body, status_code=status, media_type=PROBLEM_JSON, headers=headers)


def field_problems(error: RequestValidationError) -> list[FieldProblem]:
    """Each bad field, without the value sent (it may be a password)."""
    return [FieldProblem(loc=list(e["loc"]), msg=e["msg"], type=e["type"]) for e in error.errors()]


def validation_detail(problems: Sequence[FieldProblem]) -> str:
    """One sentence naming each bad field: ``query.offset: Input should be ...; body.name: ...``."""
    return "; ".join(f"{'.'.join(str(part) for part in p.loc)}: {p.msg}" for p in problems)


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(ServiceRefusal)
    async def refusal(request: Request, error: ServiceRefusal) -> Response:
        if error.status == 403:
            user = getattr(request.state, "user", None)
            audit.refused(request, 403, f"{user.name} ({user.role.value})" if user else "?", error.detail)
        return problem_response(request, error.status, error.detail)

    @app.exception_handler(HTTPException)
    async def http_refusal(request: Request, error: HTTPException) -> Response:
        detail = error.detail if isinstance(error.detail, str) else HTTPStatus(error.status_code).description
        return problem_response(request, error.status_code, detail, headers=error.headers)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, error: RequestValidationError) -> Response:
        problems = field_problems(error)
        return problem_response(request, 422, validation_detail(problems), errors=problems)

    async def part_down(request: Request, error: Exception) -> Response:
        down = unavailable(error)
        assert down is not None
        return problem_response(request, down.status, down.detail)

    for part in (StoreUnavailable, ManagementError, httpx.TransportError):
        app.add_exception_handler(part, part_down)


def problem_schemas() -> dict[str, Any]:
    """The Problem schema and the ones it uses, for the OpenAPI document's components."""
    schema = Problem.model_json_schema(ref_template="#/components/schemas/{model}", mode="serialization")
    nested = schema.pop("$defs", {})
    return {**nested, "Problem": schema}
