"""The HTTP API on a test's own slice of the real broker and a real store, driven over TestClient.

Setup goes through the same services the API uses (``Service``), on the app's own event loop;
what is being tested goes through HTTP.
"""

from __future__ import annotations

import uuid
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from http import HTTPStatus
from typing import Any, TypeVar

import pytest
from fastapi.testclient import TestClient
from pymongo import MongoClient

from fleetbus.api.app import create_app
from fleetbus.api.service import Service
from fleetbus.api.services.sessions import Origin
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.use_cases import machine_for
from fleetbus.settings import Settings
from fleetbus.workers.store.missions import Mission
from tests.support import Bus

T = TypeVar("T")
PASSWORD = "correct horse battery"
SQUARE = {"polygon": [{"x": 0, "y": 0}, {"x": 20, "y": 0}, {"x": 20, "y": 20}, {"x": 0, "y": 20}]}
READY_PLAN = {"geofence": SQUARE, "risk_assessment": {"level": "low", "summary": "indoor, no people"}}

#: The shortest way to each state, per use case (steps taken directly in the store for setup).
PATHS = {
    "hazard-response": [
        MissionState.FILED,
        MissionState.APPROVED,
        MissionState.IN_PROGRESS,
        MissionState.REVIEWING,
    ],
    "survey": [MissionState.IN_PROGRESS, MissionState.REVIEWING],
}


def problem(status: int, detail: str, instance: str) -> dict[str, Any]:
    """The body of a refusal: RFC 9457 problem details."""
    title = HTTPStatus(status).phrase
    return {"type": "about:blank", "title": title, "status": status, "detail": detail, "instance": instance}


def refusal(reply: Any) -> tuple[int, str, Any]:
    """A reply's status, media type and body, to compare with ``(status, PROBLEM_JSON, problem(...))``."""
    return reply.status_code, reply.headers["content-type"], reply.json()


PROBLEM_JSON = "application/problem+json"


@dataclass
class Api:
    client: TestClient
    service: Service
    bus: Bus
    tokens: dict[str, str] = field(default_factory=dict)

    def run(self, work: Callable[[], Awaitable[T]]) -> T:
        """Run a coroutine on the app's event loop (where its store connection lives)."""
        assert self.client.portal is not None
        return self.client.portal.call(work)

    def user(
        self, name: str, role: UserRole, kind: RobotKind | None = None, password: str | None = PASSWORD
    ) -> str:
        """A user made through the service (as an admin would), with its broker account."""
        self.bus.api.delete_user(name)  # broker users are broker-wide: one left by an aborted run
        self.run(lambda: self.service.accounts.create(name, password, role, kind, by="test"))
        return name

    def session(self, name: str) -> str:
        """A new session's token for ``name`` (begun in the store, as a login does, but without the
        password check: for a role that cannot log in)."""
        origin = Origin("127.0.0.1", "test")
        return self.run(lambda: self.service.sessions.begin(name, origin)).value

    def token(self, name: str) -> str:
        """A token for ``name``: logged in over HTTP, or a session begun when login is refused (inactive)."""
        if name not in self.tokens:
            reply = self.client.post("/auth/token", data={"username": name, "password": PASSWORD})
            if reply.status_code == 200:
                self.tokens[name] = reply.json()["access_token"]
            else:
                self.tokens[name] = self.session(name)
        return self.tokens[name]

    def headers(self, name: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token(name)}"}

    def call(self, name: str, method: str, path: str, **kwargs: Any) -> Any:
        return self.client.request(method, path, headers=self.headers(name), **kwargs)

    def mission(
        self,
        state: MissionState = MissionState.PLANNING,
        use_case: str = "hazard-response",
        owner: str = "client1",
    ) -> Mission:
        """A mission with a ready plan, walked to ``state`` directly in the store."""
        store, now = self.service.repositories, datetime.now(timezone.utc)
        mission = self.run(
            lambda: store.missions.create_mission(use_case, f"{use_case} test", owner, READY_PLAN, now)
        )
        machine, mission_id = machine_for(use_case), mission.mission_id
        for target in PATHS[use_case]:
            if mission.state is state:
                break
            source = machine.step(mission.state, target, None).source
            mission = self.run(
                lambda s=source, t=target: store.missions.transition_mission(mission_id, s, t, "test", now)
            )
        assert mission.state is state, f"{use_case} has no path to {state.value} here"
        return mission


@contextmanager
def running_api(
    bus: Bus,
    settings: Settings | None = None,
    *,
    client_host: str = "127.0.0.1",
    base_url: str = "http://testserver",
    public_url: str | None = None,
    management_url: str | None = None,
) -> Iterator[Api]:
    """The app on ``bus`` (its virtual host, as administrator) and its store; broker users removed after.
    Its requests come from ``client_host`` (by default the API's own machine, where the login hands out
    broker passwords over plain HTTP) to ``base_url``."""
    settings = settings or bus.settings
    app = create_app(settings, bus.admin_url, management_url or bus.endpoint.management_url, public_url)
    with TestClient(app, base_url=base_url, client=(client_host, 50000)) as client:
        service: Service = app.state.service
        api = Api(client, service, bus)
        try:
            yield api
        finally:
            for user in api.run(service.repositories.users.users):
                bus.api.delete_user(user.name)


@contextmanager
def running_api_on_each_store(request: pytest.FixtureRequest, bus: Bus) -> Iterator[Api]:
    """The app on ``bus`` with the store the test is parametrised with: SQLite, or ("mongodb") a
    MongoDB database of its own, dropped afterwards (the worker shares it)."""
    database = None
    if request.param == "mongodb":
        database = f"test_{uuid.uuid4().hex[:12]}"
        url = request.getfixturevalue("mongodb_url")
        bus.settings = bus.settings.updated(mongodb_url=f"{url.rstrip('/')}/{database}")
    try:
        with running_api(bus) as running:
            yield running
    finally:
        if bus.settings.mongodb_url and database:
            with MongoClient(bus.settings.mongodb_url, serverSelectionTimeoutMS=5000) as client:
                client.drop_database(database)
