"""Every endpoint against every role, on the real app, store and broker: the roles an endpoint
admits get its success status; every other role gets 403, the refusal is logged, and nothing
changes. The table here is the specification; a test checks the OpenAPI document agrees."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import pytest

from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.envelope import build_event
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import ACTIVE_ROLES, UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.alerts import NewAlert
from fleetbus.workers.store.recordings import RecordedMessage
from tests import factories
from tests.api.support import PASSWORD, PROBLEM_JSON, READY_PLAN, Api, running_api
from tests.support import fresh_bus

R, S = UserRole, MissionState
USERS = {
    R.ADMIN: "admin1",
    R.CLIENT: "client1",
    R.PLANNER: "planner1",
    R.SUPERVISOR: "super1",
    R.OPERATOR: "oper1",
    R.ROBOT: "robot1",
    R.GUEST: "visitor1",
    R.INACTIVE: "idle1",
}


@dataclass(frozen=True)
class Call:
    method: str
    path: str
    json: Any = None
    unchanged: Callable[[], bool] | None = None
    """For a refused call: whether what it would have changed is as it was."""


@dataclass(frozen=True)
class Case:
    method: str
    route: str
    allowed: frozenset[UserRole]
    success: int
    prepare: Callable[[Api, UserRole], Call]
    cleanup: Callable[[Api], None] = field(default=lambda api: None)

    @property
    def id(self) -> str:
        return f"{self.method} {self.route}"


def fixed(method: str, path: str, json: Any = None) -> Callable[[Api, UserRole], Call]:
    return lambda api, role: Call(method, path, json)


_targets = itertools.count()


def throwaway(api: Api, role: UserRole) -> str:
    return api.user(f"target{next(_targets)}-{role.value}", R.GUEST)


def user_change(method: str, suffix: str, json: Any) -> Callable[[Api, UserRole], Call]:
    def prepare(api: Api, role: UserRole) -> Call:
        name = throwaway(api, role)
        before = api.run(lambda: api.service.repositories.users.get_user(name))
        return Call(
            method,
            f"/users/{name}{suffix}",
            json,
            lambda: api.run(lambda: api.service.repositories.users.get_user(name)) == before,
        )

    return prepare


def step_for(api: Api, role: UserRole) -> Call:
    """A step this role may take, from a mission put in the state it starts from."""
    steps = {
        R.CLIENT: (S.PLANNING, S.CLOSED),
        R.PLANNER: (S.PLANNING, S.FILED),
        R.SUPERVISOR: (S.FILED, S.APPROVED),
        R.OPERATOR: (S.IN_PROGRESS, S.INTERRUPTED),
    }
    source, target = steps.get(role, (S.PLANNING, S.FILED))
    mission = api.mission(source)
    state = lambda: api.run(lambda: api.service.repositories.missions.get_mission(mission.mission_id)).state  # noqa: E731
    return Call(
        "POST", f"/missions/{mission.mission_id}/transitions", {"to": target.value}, lambda: state() is source
    )


def user_of(api: Api, name: str) -> Any:
    return api.run(lambda: api.service.repositories.users.get_user(name))


def release_operator(api: Api) -> None:
    """Free oper1 and robot1 for the next case: unmount, check out."""
    store = api.service.repositories
    supervisor = user_of(api, "super1")
    for mount in api.run(lambda: store.channels.mounts(robot="robot1")):
        api.run(lambda m=mount: api.service.channels.unmount(supervisor, m.robot))
    for check_in in api.run(lambda: store.channels.check_ins(operator="oper1")):
        api.run(lambda c=check_in: store.channels.check_out("oper1", c.mission_id))


def mounted_robot(api: Api, role: UserRole) -> Call:
    mission, operator = api.mission(S.APPROVED), user_of(api, "oper1")
    api.run(lambda: api.service.channels.mount(operator, "robot1", mission.mission_id))
    return Call(
        "DELETE",
        "/mounts/robot1",
        unchanged=lambda: bool(api.run(lambda: api.service.repositories.channels.mounts(robot="robot1"))),
    )


def checked_in(api: Api, role: UserRole) -> Call:
    mission, operator = api.mission(S.IN_PROGRESS), user_of(api, "oper1")
    api.run(lambda: api.service.channels.check_in(operator, mission.mission_id))
    return Call("POST", f"/missions/{mission.mission_id}/check-out")


def owned_mission(
    suffix: str, method: str = "GET", json: Any = None, state: MissionState = S.PLANNING
) -> Callable[[Api, UserRole], Call]:
    return lambda api, role: Call(method, f"/missions/{api.mission(state).mission_id}{suffix}", json)


def comment(api: Api, role: UserRole) -> Call:
    """A comment on a mission of client1's, which a refused one leaves without."""
    mission = api.mission(S.PLANNING).mission_id
    count = lambda: api.run(lambda: api.service.repositories.comments.count_comments(mission))  # noqa: E731
    return Call("POST", f"/missions/{mission}/comments", {"text": f"by {role.value}"}, lambda: count() == 0)


def recorded_message(api: Api, role: UserRole) -> Call:
    """A message in the recording, to be traced."""
    record = RecordedMessage(
        key=f"traced-{role.value}",
        type="tf",
        recorded_at=datetime.now(timezone.utc),
        exchange="robot1.events",
        routing_key="robot1.tf",
        user_id="robot1",
        robot_id="robot1",
        message_id=f"traced-{role.value}",
        document={"frame": "/a"},
    )
    api.run(lambda: api.service.recording.write_recorded([record]))
    return Call("GET", f"/recording/trace/{record.message_id}")


def warden_service(action: str) -> Callable[[Api, UserRole], Call]:
    """A warden registered for this case, to take out of service (or, taken out, to put back)."""

    def prepare(api: Api, role: UserRole) -> Call:
        name, store = f"warden-{action}-{role.value}", api.service.repositories
        api.run(lambda: store.hazards.register_robot(name, RobotKind.WARDEN.value))
        if action == "in":
            api.run(lambda: store.hazards.set_in_service(name, False, "test", datetime.now(timezone.utc)))
        before = api.run(lambda: store.hazards.robots())

        return Call(
            "POST",
            f"/team/{name}/{action}",
            unchanged=lambda: api.run(lambda: store.hazards.robots()) == before,
        )

    return prepare


_hazard_seqs = itertools.count()
EPOCH = "20261125T000000000Z-0000beef"


def hazard_claim(api: Api, role: UserRole) -> Call:
    """An announced hazard of its own, to claim for a warden in service."""
    store = api.service.repositories.hazards
    warden = f"warden-claim-{role.value}"
    api.run(lambda: store.register_robot(warden, RobotKind.WARDEN.value))
    at, seq = datetime.now(timezone.utc), next(_hazard_seqs)
    sent = build_event("hazard", "explorer1", EPOCH, seq, factories.hazard(seq, f"for {role.value}"))
    event = sent.model_dump(mode="json")
    hazard = api.run(lambda: store.add_hazard("default", "explorer1", EPOCH, seq, event, at, held=False))
    return Call(
        "POST",
        f"/hazards/default/{hazard.hazard_id}/claim",
        {"warden": warden},
        lambda: api.run(lambda: store.get_hazard("default", hazard.hazard_id)) == hazard,
    )


def raised_alert(api: Api, role: UserRole) -> Call:
    """An alert of its own, raised in the store, to acknowledge."""
    store = api.service.repositories.alerts
    now = datetime.now(timezone.utc)
    new = NewAlert("robot-stale", f"robot ack-{role.value}", now, "never heard from")
    [alert] = api.run(lambda: store.raise_alerts([new], now))
    return Call(
        "POST",
        f"/alerts/{alert.id}/acknowledge",
        unchanged=lambda: api.run(lambda: store.get_alert(alert.id)) == alert,
    )


def own_session(api: Api, role: UserRole) -> Call:
    """Another session of the caller's own, to end."""
    token = api.session(USERS[role])
    sid = api.service.secrets.tokens.read(token).session
    alive = lambda: api.run(lambda: api.service.repositories.sessions.get_session(sid)) is not None  # noqa: E731
    return Call("DELETE", f"/users/me/sessions/{sid}", unchanged=alive)


def users_sessions(api: Api, role: UserRole) -> Call:
    """A throwaway user with a session, whose sessions are to end."""
    name = throwaway(api, role)
    sid = api.service.secrets.tokens.read(api.session(name)).session
    alive = lambda: api.run(lambda: api.service.repositories.sessions.get_session(sid)) is not None  # noqa: E731
    return Call("DELETE", f"/users/{name}/sessions", unchanged=alive)


READERS = frozenset({R.ADMIN, R.CLIENT, R.PLANNER, R.SUPERVISOR, R.OPERATOR, R.GUEST})
ANALYSTS = frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR})
CASES = [
    Case("GET", "/users/me", ACTIVE_ROLES, 200, fixed("GET", "/users/me")),
    Case(
        "PUT",
        "/users/me/password",
        ACTIVE_ROLES,
        204,
        fixed("PUT", "/users/me/password", {"current_password": PASSWORD, "new_password": PASSWORD}),
    ),
    Case("GET", "/users/me/sessions", ACTIVE_ROLES, 200, fixed("GET", "/users/me/sessions")),
    Case("DELETE", "/users/me/sessions/{session_id}", ACTIVE_ROLES, 204, own_session),
    Case("GET", "/users", frozenset({R.ADMIN, R.SUPERVISOR}), 200, fixed("GET", "/users")),
    Case(
        "POST",
        "/users",
        frozenset({R.ADMIN}),
        201,
        lambda api, role: Call(
            "POST",
            "/users",
            {"name": f"made-by-{role.value}", "role": "client"},
            lambda: api.run(lambda: api.service.repositories.users.get_user(f"made-by-{role.value}")) is None,
        ),
    ),
    Case("GET", "/users/{name}", frozenset({R.ADMIN, R.SUPERVISOR}), 200, fixed("GET", "/users/robot1")),
    Case(
        "PUT",
        "/users/{name}/role",
        frozenset({R.ADMIN}),
        200,
        user_change("PUT", "/role", {"role": "client"}),
    ),
    Case(
        "PUT",
        "/users/{name}/password",
        frozenset({R.ADMIN}),
        204,
        user_change("PUT", "/password", {"password": "another long one"}),
    ),
    Case(
        "PUT",
        "/users/{name}/use-cases",
        frozenset({R.ADMIN}),
        200,
        user_change("PUT", "/use-cases", {"use_cases": ["survey"]}),
    ),
    Case("DELETE", "/users/{name}", frozenset({R.ADMIN}), 204, user_change("DELETE", "", None)),
    Case("GET", "/users/{name}/sessions", frozenset({R.ADMIN}), 200, fixed("GET", "/users/robot1/sessions")),
    Case("DELETE", "/users/{name}/sessions", frozenset({R.ADMIN}), 200, users_sessions),
    Case("GET", "/registry/drift", frozenset({R.ADMIN}), 200, fixed("GET", "/registry/drift")),
    Case("POST", "/registry/repair", frozenset({R.ADMIN}), 200, fixed("POST", "/registry/repair")),
    Case("GET", "/use-cases", ACTIVE_ROLES, 200, fixed("GET", "/use-cases")),
    Case(
        "POST",
        "/missions",
        frozenset({R.CLIENT, R.PLANNER}),
        201,
        fixed("POST", "/missions", {"use_case": "survey", "title": "matrix", "plan": READY_PLAN}),
    ),
    Case("GET", "/missions", READERS, 200, fixed("GET", "/missions")),
    Case("GET", "/missions/{mission_id}", READERS, 200, owned_mission("")),
    Case(
        "PUT",
        "/missions/{mission_id}/plan",
        frozenset({R.CLIENT, R.PLANNER}),
        200,
        owned_mission("/plan", "PUT", READY_PLAN),
    ),
    Case(
        "POST",
        "/missions/{mission_id}/transitions",
        frozenset({R.CLIENT, R.PLANNER, R.SUPERVISOR, R.OPERATOR}),
        200,
        step_for,
    ),
    Case("GET", "/missions/{mission_id}/events", READERS - {R.GUEST}, 200, owned_mission("/events")),
    Case("GET", "/missions/{mission_id}/comments", READERS, 200, owned_mission("/comments")),
    Case("POST", "/missions/{mission_id}/comments", READERS - {R.GUEST}, 201, comment),
    Case(
        "POST",
        "/missions/{mission_id}/check-in",
        frozenset({R.OPERATOR}),
        200,
        owned_mission("/check-in", "POST", state=S.IN_PROGRESS),
        release_operator,
    ),
    Case(
        "POST", "/missions/{mission_id}/check-out", frozenset({R.OPERATOR}), 200, checked_in, release_operator
    ),
    Case(
        "POST",
        "/mounts",
        frozenset({R.OPERATOR}),
        201,
        lambda api, role: Call(
            "POST", "/mounts", {"robot": "robot1", "mission_id": api.mission(S.APPROVED).mission_id}
        ),
        release_operator,
    ),
    Case("GET", "/mounts", frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}), 200, fixed("GET", "/mounts")),
    Case(
        "DELETE",
        "/mounts/{robot}",
        frozenset({R.SUPERVISOR, R.OPERATOR}),
        200,
        mounted_robot,
        release_operator,
    ),
    Case(
        "GET", "/channels/changes", frozenset({R.ADMIN, R.SUPERVISOR}), 200, fixed("GET", "/channels/changes")
    ),
    Case(
        "GET",
        "/channels/bindings",
        frozenset({R.ADMIN, R.SUPERVISOR}),
        200,
        fixed("GET", "/channels/bindings"),
    ),
    Case(
        "POST",
        "/channels/bindings/repair",
        frozenset({R.ADMIN, R.SUPERVISOR}),
        200,
        fixed("POST", "/channels/bindings/repair"),
    ),
    Case(
        "GET",
        "/beacons/discards",
        frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}),
        200,
        fixed("GET", "/beacons/discards"),
    ),
    Case("GET", "/recording/types", ANALYSTS, 200, fixed("GET", "/recording/types")),
    Case(
        "GET",
        "/recording/records/{message_type}",
        ANALYSTS,
        200,
        fixed("GET", "/recording/records/tf"),
    ),
    Case("GET", "/recording/timeline/{robot}", ANALYSTS, 200, fixed("GET", "/recording/timeline/robot1")),
    Case("GET", "/recording/trace/{message_id}", ANALYSTS, 200, recorded_message),
    Case("GET", "/recording/evaluation", ANALYSTS | {R.PLANNER}, 200, fixed("GET", "/recording/evaluation")),
    Case("GET", "/recording/growth", ANALYSTS | {R.PLANNER}, 200, fixed("GET", "/recording/growth")),
    Case("GET", "/team", frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}), 200, fixed("GET", "/team")),
    Case("POST", "/team/{robot}/out", frozenset({R.SUPERVISOR, R.OPERATOR}), 200, warden_service("out")),
    Case("POST", "/team/{robot}/in", frozenset({R.SUPERVISOR, R.OPERATOR}), 200, warden_service("in")),
    Case("GET", "/hazards", frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}), 200, fixed("GET", "/hazards")),
    Case(
        "POST",
        "/hazards/{mission_id}/{hazard_id}/{step}",
        frozenset({R.SUPERVISOR, R.OPERATOR}),
        200,
        hazard_claim,
    ),
    Case("GET", "/alerts", frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}), 200, fixed("GET", "/alerts")),
    Case(
        "POST",
        "/alerts/{alert_id}/acknowledge",
        frozenset({R.ADMIN, R.SUPERVISOR, R.OPERATOR}),
        200,
        raised_alert,
    ),
]


@pytest.fixture(scope="module")
def api(
    endpoint: BrokerEndpoint, management: ManagementAPI, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Api]:
    """One app for the whole table (a fresh virtual host and store); a user of every role."""
    with (
        fresh_bus(endpoint, management, tmp_path_factory.mktemp("roles")) as bus,
        running_api(bus) as running,
    ):
        for role, name in USERS.items():
            running.user(name, role, RobotKind.EXPLORER if role is R.ROBOT else None)
        yield running


@pytest.mark.parametrize("role", list(UserRole), ids=lambda r: r.value)
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_each_role_against_each_endpoint(
    api: Api, case: Case, role: UserRole, caplog: pytest.LogCaptureFixture
) -> None:
    call = case.prepare(api, role)
    api.token(USERS[role])  # logged in (or, inactive, refused) before the call under test
    caplog.clear()
    try:
        with caplog.at_level(logging.WARNING, "fleetbus.api.security"):
            reply = api.call(USERS[role], call.method, call.path, json=call.json)
        if role in case.allowed:
            assert reply.status_code == case.success, reply.text
            return
        assert (reply.status_code, reply.headers["content-type"]) == (403, PROBLEM_JSON), reply.text
        assert reply.json()["detail"].startswith(f"role {role.value} may not do")
        logged = [r.getMessage() for r in caplog.records if r.name == "fleetbus.api.security"]
        who = f"{USERS[role]} ({role.value})"
        assert logged == [
            f"refused 403: {call.method} {call.path} from 127.0.0.1 as {who}: {reply.json()['detail']}"
        ]
        if call.unchanged is not None:
            assert call.unchanged(), "a refused call changed nothing"
    finally:
        case.cleanup(api)


def test_the_table_covers_every_endpoint_and_matches_the_openapi_document(api: Api) -> None:
    document = api.client.get("/openapi.json").json()
    declared = {
        (method.upper(), path): frozenset(UserRole(r) for r in operation["x-roles"])
        for path, operations in document["paths"].items()
        for method, operation in operations.items()
        if "x-roles" in operation
    }
    assert declared == {(case.method, case.route): case.allowed for case in CASES}
    public = {
        (m.upper(), p) for p, ops in document["paths"].items() for m, op in ops.items() if "x-roles" not in op
    }
    assert public == {
        ("POST", "/auth/token"),
        ("POST", "/auth/revoke"),
        ("GET", "/health"),
        ("GET", "/ca.pem"),
    }
