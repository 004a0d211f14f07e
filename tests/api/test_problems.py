"""One error model for every refusal of the HTTP API: RFC 9457 problem details, as
``application/problem+json``; validation errors name each bad field where it is; the OpenAPI
document describes the Problem once and lists it on every operation with the statuses the route
can answer."""

from __future__ import annotations

import socket
import sqlite3
from collections.abc import Iterator

import pytest

from fleetbus.schemas.roles import UserRole
from tests.api.support import PASSWORD, PROBLEM_JSON, Api, problem, refusal, running_api
from tests.support import Bus

PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}


@pytest.fixture
def api(bus: Bus) -> Iterator[Api]:
    with running_api(bus) as running:
        running.user("admin1", UserRole.ADMIN)
        yield running


def test_a_validation_error_names_each_bad_field_where_it_is(api: Api) -> None:
    reply = api.call("admin1", "GET", "/hazards", params={"limit": 0, "offset": -1})
    limit, offset = "Input should be greater than or equal to 1", "Input should be greater than or equal to 0"
    detail = f"query.limit: {limit}; query.offset: {offset}"
    errors = [
        {"loc": ["query", "limit"], "msg": limit, "type": "greater_than_equal"},
        {"loc": ["query", "offset"], "msg": offset, "type": "greater_than_equal"},
    ]
    assert refusal(reply) == (422, PROBLEM_JSON, {**problem(422, detail, "/hazards"), "errors": errors})
    bad_body = api.call("admin1", "POST", "/users", json={"name": "bob", "role": "captain"})
    assert [e["loc"] for e in refusal(bad_body)[2]["errors"]] == [["body", "role"]]
    api.user("ops1", UserRole.OPERATOR)
    no_warden = api.call("ops1", "POST", "/hazards/m1/1/claim", json={"warden": ""})
    assert [e["loc"] for e in refusal(no_warden)[2]["errors"]] == [["body", "warden"]]


def test_the_services_own_refusals_are_problems_without_field_errors(api: Api) -> None:
    itself = api.call("admin1", "DELETE", "/users/admin1")
    assert refusal(itself) == (
        422,
        PROBLEM_JSON,
        problem(422, "an admin cannot remove itself", "/users/admin1"),
    )
    change = {"current_password": "not it", "new_password": PASSWORD}
    wrong = api.call("admin1", "PUT", "/users/me/password", json=change)
    assert refusal(wrong) == (
        422,
        PROBLEM_JSON,
        problem(422, "the current password is wrong", "/users/me/password"),
    )
    missing = api.call("admin1", "GET", "/users/nobody")
    assert refusal(missing) == (404, PROBLEM_JSON, problem(404, "no user 'nobody'", "/users/nobody"))
    no_route = api.client.get("/no/such/thing")
    assert refusal(no_route) == (404, PROBLEM_JSON, problem(404, "Not Found", "/no/such/thing"))


def test_a_locked_store_is_a_503_problem_and_changes_nothing(api: Api) -> None:
    before = api.run(lambda: api.service.repositories.users.get_user("admin1"))
    api.token("admin1")  # logged in before the lock (a login writes its session)
    locker = sqlite3.connect(api.bus.settings.sqlite_path, isolation_level=None)
    locker.execute("BEGIN EXCLUSIVE")
    try:
        change = {"current_password": PASSWORD, "new_password": "another good password"}
        reply = api.call("admin1", "PUT", "/users/me/password", json=change)
    finally:
        locker.execute("ROLLBACK")
        locker.close()
    status, media_type, body = refusal(reply)
    assert (status, media_type, body["title"], body["instance"]) == (
        503,
        PROBLEM_JSON,
        "Service Unavailable",
        "/users/me/password",
    )
    assert body["detail"].startswith("the store is unavailable: SQLite") and "locked" in body["detail"]
    assert api.run(lambda: api.service.repositories.users.get_user("admin1")) == before


def test_a_management_api_out_of_reach_is_a_503_problem(api: Api) -> None:
    """The mount bindings are read from the broker's management API: with nothing listening where
    it should be, the service answers 503 and says which part is missing."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        closed = f"http://127.0.0.1:{probe.getsockname()[1]}/"  # bound, never listening: refused
        with running_api(api.bus, management_url=closed) as cut_off:  # the same store and users
            reply = cut_off.call("admin1", "GET", "/channels/bindings")
    status, media_type, body = refusal(reply)
    assert (status, media_type, body["instance"]) == (503, PROBLEM_JSON, "/channels/bindings")
    assert body["detail"].startswith("the broker's management API is unreachable"), body


def test_the_document_describes_the_problem_once_and_lists_it_for_every_refusal(api: Api) -> None:
    document = api.client.get("/openapi.json").json()
    schemas = document["components"]["schemas"]
    assert schemas["Problem"]["required"] == ["title", "status", "detail", "instance"]
    assert "HTTPValidationError" not in schemas, "FastAPI's own 422 body is never sent"
    for path, operations in document["paths"].items():
        assert not path.startswith(("/console", "/static")), "the console's pages are not the JSON API"
        for method, operation in operations.items():
            refusals = {status: r for status, r in operation["responses"].items() if status >= "400"}
            where = f"{method.upper()} {path}"
            for status, response in refusals.items():
                assert response["content"] == {PROBLEM_JSON: {"schema": PROBLEM_REF}}, (where, status)
            if "x-roles" in operation:
                assert {"401", "403", "503"} <= refusals.keys(), where
                assert "WWW-Authenticate" in refusals["401"]["headers"], where
    login = document["paths"]["/auth/token"]["post"]["responses"]
    assert sorted(login) == ["200", "400", "401", "403", "422", "429", "503"]
    assert "Retry-After" in login["429"]["headers"]
    assert list(document["paths"]["/ca.pem"]["get"]["responses"]["200"]["content"]) == ["text/plain"]
    # a path of plain text parameters can refuse none of them: no 422 where nothing can be invalid
    assert sorted(document["paths"]["/missions/{mission_id}"]["get"]["responses"]) == [
        "200",
        "401",
        "403",
        "404",
        "503",
    ]
