"""`fleetbus api` in a process of its own on a test's slice of the broker, with a logged-in user of
each role asked for, for the outside peers that check it over real HTTP."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import httpx

from tests.api.server import api_server
from tests.support import Bus

PASSWORD = "correct horse battery"
#: Every role a person logs in with.
ROLES = ("admin", "supervisor", "planner", "operator", "client", "guest")


@dataclass(frozen=True)
class ServedApi:
    base: str
    names: dict[str, str]
    """The user of each role."""
    tokens: dict[str, str] = field(default_factory=dict)
    """A bearer token per role."""

    def document(self) -> dict[str, Any]:
        return httpx.get(f"{self.base}/openapi.json", timeout=30).json()


@contextmanager
def served_api(bus: Bus, roles: Sequence[str], prefix: str = "peer", **settings: str) -> Iterator[ServedApi]:
    """The API on ``bus`` (with ``settings``, ``FLEETBUS_...``) and a user ``<prefix>-<role>`` of
    each of ``roles``: the admin made by `fleetbus api create-admin`, the others by the admin over
    HTTP. At the end, the broker accounts of every user its store holds then, whoever made them,
    are removed."""
    admin = f"{prefix}-admin"
    with (
        api_server(bus, admin, PASSWORD, **settings) as base,
        httpx.Client(base_url=base, timeout=60) as http,
    ):

        def log_in(name: str) -> str:
            reply = http.post("/auth/token", data={"username": name, "password": PASSWORD})
            assert reply.status_code == 200, reply.text
            return reply.json()["access_token"]

        as_admin = {"Authorization": f"Bearer {log_in(admin)}"}
        served = ServedApi(base, {role: f"{prefix}-{role}" for role in roles})
        for role, name in served.names.items():
            if role != "admin":
                bus.api.delete_user(name)  # broker users are broker-wide: one left by an aborted run
                user = {"name": name, "password": PASSWORD, "role": role}
                made = http.post("/users", json=user, headers=as_admin)
                assert made.status_code == 201, made.text
            served.tokens[role] = log_in(name)
        try:
            yield served
        finally:
            users = http.get("/users", headers=as_admin)
            for user in users.json() if users.status_code == 200 else []:
                bus.api.delete_user(user["name"])
