"""Login sessions end on the server: `fleetbus api` served by uvicorn in a process of its own, over
real HTTP. A token is refused at its next request once its session ends: by a logout (RFC 7009
revocation), by an admin (over HTTP or from the command line, with the same outcome), by a
password change or reset, by the user's removal, or by a login beyond the per-user bound. One
server for it all: starting one is most of the test's time."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from typer.testing import CliRunner

from fleetbus.cli import app
from tests.api.server import api_server
from tests.support import Bus

PASSWORD = "correct horse battery"
ADMIN = "sess-admin"
USER = "sess-alice"
ENDED = "the session has ended (logged out, ended by an admin, or a password change); log in again"


@pytest.fixture
def api(bus: Bus) -> Iterator[httpx.Client]:
    with (
        api_server(bus, ADMIN, PASSWORD, FLEETBUS_API_SESSIONS_PER_USER="3") as base,
        httpx.Client(base_url=base, timeout=30) as http,
    ):
        bus.api.delete_user(USER)  # broker users are broker-wide: one left by an aborted run
        made = http.post("/users", json=_user(), headers=_bearer(_log_in(http, ADMIN)))
        assert made.status_code == 201, made.text
        try:
            yield http
        finally:
            bus.api.delete_user(USER)


def _user() -> dict[str, str]:
    return {"name": USER, "password": PASSWORD, "role": "operator"}


def _log_in(http: httpx.Client, name: str, agent: str = "test-client/1", password: str = PASSWORD) -> str:
    reply = http.post(
        "/auth/token", data={"username": name, "password": password}, headers={"User-Agent": agent}
    )
    assert reply.status_code == 200, reply.text
    return reply.json()["access_token"]


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def _status(http: httpx.Client, token: str) -> int:
    return http.get("/users/me", headers=_bearer(token)).status_code


def _refused_as_ended(http: httpx.Client, token: str) -> None:
    reply = http.get("/users/me", headers=_bearer(token))
    assert (reply.status_code, reply.json()["detail"]) == (401, ENDED)


def test_a_logout_a_password_change_an_admin_the_command_line_a_removal_and_the_bound_end_sessions(
    api: httpx.Client, bus: Bus
) -> None:
    admin = _bearer(_log_in(api, ADMIN))
    laptop, phone = _log_in(api, USER, "laptop/1"), _log_in(api, USER, "phone/2")
    listed = api.get("/users/me/sessions", headers=_bearer(laptop)).json()
    assert [(s["agent"], s["address"], s["current"]) for s in listed] == [
        ("phone/2", "127.0.0.1", False),
        ("laptop/1", "127.0.0.1", True),
    ]
    assert listed[0]["begun_at"] <= listed[0]["last_seen"] < listed[0]["expires_at"]
    assert api.get(f"/users/{USER}/sessions", headers=admin).json()[0]["id"] == listed[0]["id"]

    # a logout: the token sent in the form is revoked, the other session goes on
    assert api.post("/auth/revoke", data={"token": laptop}).status_code == 200
    _refused_as_ended(api, laptop)
    assert _status(api, phone) == 200
    assert api.post("/auth/revoke", data={"token": laptop}).status_code == 200, "again: still 200"

    # the user ends one of their own sessions by its id
    tablet = _log_in(api, USER, "tablet/3")
    ended = api.delete(f"/users/me/sessions/{listed[0]['id']}", headers=_bearer(tablet))
    assert ended.status_code == 204
    _refused_as_ended(api, phone)
    again = api.delete(f"/users/me/sessions/{listed[0]['id']}", headers=_bearer(tablet))
    assert again.status_code == 404 and "no session" in again.json()["detail"]

    # a password change ends the others, not the one that changed it; an admin's reset ends all
    other = _log_in(api, USER)
    change = {"current_password": PASSWORD, "new_password": "another long password"}
    assert api.put("/users/me/password", json=change, headers=_bearer(tablet)).status_code == 204
    _refused_as_ended(api, other)
    assert _status(api, tablet) == 200
    reset = api.put(f"/users/{USER}/password", json={"password": PASSWORD}, headers=admin)
    assert reset.status_code == 204
    _refused_as_ended(api, tablet)

    # the admin ends every session of the user, over HTTP and from the command line
    first, second = _log_in(api, USER), _log_in(api, USER)
    assert api.delete(f"/users/{USER}/sessions", headers=admin).json() == {"user": USER, "ended": 2}
    _refused_as_ended(api, first)
    _refused_as_ended(api, second)
    third = _log_in(api, USER)
    env = bus.worker_env()
    env.pop("FLEETBUS_API_SECRET", None)  # the secret the server keeps itself
    done = CliRunner().invoke(app, ["api", "end-sessions", USER, "--by", "ops"], env=env)
    assert done.exit_code == 0 and f"ended 1 session(s) of {USER}" in done.output, done.output
    _refused_as_ended(api, third)
    nobody = CliRunner().invoke(app, ["api", "end-sessions", "nobody"], env=env)
    over_http = api.delete("/users/nobody/sessions", headers=admin)
    assert nobody.exit_code == 1 and over_http.status_code == 404
    assert over_http.json()["detail"] == "no user 'nobody'" and "no user 'nobody'" in nobody.output

    # disabled: its sessions end, and giving it a role back opens none of them again
    disabled = _log_in(api, USER)
    for role in ("inactive", "operator"):
        assert api.put(f"/users/{USER}/role", json={"role": role}, headers=admin).status_code == 200
    _refused_as_ended(api, disabled)

    # removed, then made again: the new account inherits no session of the old one
    kept = _log_in(api, USER)
    assert api.delete(f"/users/{USER}", headers=admin).status_code == 204
    assert api.post("/users", json=_user(), headers=admin).status_code == 201
    _refused_as_ended(api, kept)

    # a login beyond the bound (3 here) ends the user's oldest session
    tokens = [_log_in(api, USER, f"client/{n}") for n in range(4)]
    _refused_as_ended(api, tokens[0])
    assert [_status(api, token) for token in tokens[1:]] == [200, 200, 200]
    listed = api.get("/users/me/sessions", headers=_bearer(tokens[3])).json()
    assert [s["agent"] for s in listed] == ["client/3", "client/2", "client/1"]
