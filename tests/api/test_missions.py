"""Missions over HTTP: plans checked, the use case's state machine enforced with plain refusals,
concurrent steps resolved by the store, clients kept to their own missions."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from fleetbus.schemas.roles import UserRole
from tests.api.support import READY_PLAN, SQUARE, Api, running_api
from tests.support import Bus


@pytest.fixture
def api(bus: Bus) -> Iterator[Api]:
    with running_api(bus) as running:
        for name, role in (
            ("client1", UserRole.CLIENT),
            ("client2", UserRole.CLIENT),
            ("planner1", UserRole.PLANNER),
            ("super1", UserRole.SUPERVISOR),
        ):
            running.user(name, role)
        yield running


def create(
    api: Api, who: str = "client1", use_case: str = "hazard-response", plan: dict | None = None
) -> str:
    reply = api.call(
        who, "POST", "/missions", json={"use_case": use_case, "title": "Fire", "plan": plan or {}}
    )
    assert reply.status_code == 201, reply.text
    return reply.json()["mission_id"]


def step(api: Api, who: str, mission_id: str, to: str) -> tuple[int, str]:
    reply = api.call(who, "POST", f"/missions/{mission_id}/transitions", json={"to": to})
    return reply.status_code, reply.json().get("detail") or reply.json()["state"]


def test_a_mission_goes_through_its_use_case_with_plain_refusals(api: Api) -> None:
    mission = create(api)
    assert step(api, "super1", mission, "in_progress") == (
        409,
        f"mission {mission}: cannot go from planning to in_progress; the mission is planning; "
        "allowed next: filed, closed",
    )
    assert step(api, "planner1", mission, "filed") == (
        409,
        f"mission {mission} cannot become filed: the plan has no geofence; the plan has no risk assessment",
    )
    edited = api.call("planner1", "PUT", f"/missions/{mission}/plan", json=READY_PLAN)
    assert edited.status_code == 200 and edited.json()["allowed_next"] == ["filed", "closed"]
    assert step(api, "planner1", mission, "filed") == (200, "filed")
    assert step(api, "client1", mission, "approved") == (
        403,
        f"mission {mission}: filed -> approved (approve the mission) is for supervisor, not client",
    )
    late_edit = api.call("client1", "PUT", f"/missions/{mission}/plan", json=READY_PLAN)
    assert (late_edit.status_code, late_edit.json()["detail"]) == (
        409,
        f"mission {mission} is filed: its plan can change only in planning",
    )
    for who, to in (
        ("super1", "approved"),
        ("super1", "in_progress"),
        ("super1", "reviewing"),
        ("client1", "closed"),
    ):
        assert step(api, who, mission, to) == (200, to)
    detail = api.call("client1", "GET", f"/missions/{mission}").json()
    assert [(h["source"], h["target"], h["by"]) for h in detail["history"]] == [
        (None, "planning", "client1"),
        ("planning", "filed", "planner1"),
        ("filed", "approved", "super1"),
        ("approved", "in_progress", "super1"),
        ("in_progress", "reviewing", "super1"),
        ("reviewing", "closed", "client1"),
    ]
    assert step(api, "super1", mission, "planning")[1].endswith("allowed next: none (the mission is over)")


def test_a_survey_has_no_filing(api: Api) -> None:
    mission = create(api, use_case="survey", plan={"geofence": SQUARE})
    assert step(api, "planner1", mission, "filed") == (
        409,
        f"mission {mission}: use case 'survey' has no state 'filed'; the mission is planning; "
        "allowed next: in_progress, closed",
    )
    assert step(api, "super1", mission, "in_progress") == (200, "in_progress")


def test_a_plan_outside_its_geofence_is_refused_naming_each_problem(api: Api) -> None:
    plan = {"geofence": SQUARE, "points_of_interest": [{"name": "dock", "x": 30, "y": 3}]}
    reply = api.call("client1", "POST", "/missions", json={"use_case": "survey", "title": "x", "plan": plan})
    assert reply.status_code == 422
    assert "points_of_interest.0 'dock' (30.0, 3.0) is outside the geofence" in reply.text
    unknown = api.call("client1", "POST", "/missions", json={"use_case": "dance", "title": "x"})
    assert (unknown.status_code, unknown.json()["detail"]) == (
        422,
        "unknown use case 'dance'; use cases: hazard-response, survey",
    )
    assert api.call("super1", "GET", "/missions").json() == []


def race(api: Api, mission: str, steps: dict[str, str]) -> dict[str, tuple[int, str]]:
    """Each user takes its step on the mission at the same time."""
    results: dict[str, tuple[int, str]] = {}

    def take(who: str) -> None:
        results[who] = step(api, who, mission, steps[who])

    threads = [threading.Thread(target=take, args=(who,)) for who in steps]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    return results


def test_of_two_concurrent_steps_one_wins(api: Api) -> None:
    """Starting and cancelling a survey exclude each other: whichever lands first, the other is refused."""
    steps = {"super1": "in_progress", "client1": "closed"}
    api.token("super1"), api.token("client1")
    for _ in range(5):
        mission = create(api, use_case="survey", plan={"geofence": SQUARE})
        results = race(api, mission, steps)
        assert sorted(code for code, _ in results.values()) == [200, 409], results
        [(winner, (_, state))] = [(who, r) for who, r in results.items() if r[0] == 200]
        [(_, detail)] = [r for r in results.values() if r[0] == 409]
        assert state == steps[winner]
        assert f"the mission is {state}" in detail or f"it is now {state}" in detail, detail
        history = api.call("super1", "GET", f"/missions/{mission}").json()["history"]
        assert [(h["source"], h["target"]) for h in history[1:]] == [("planning", state)]


def test_clients_see_only_their_own_missions(api: Api) -> None:
    mine, theirs = create(api, "client1"), create(api, "client2")
    assert [m["mission_id"] for m in api.call("client1", "GET", "/missions").json()] == [mine]
    assert [m["mission_id"] for m in api.call("planner1", "GET", "/missions").json()] == [mine, theirs]
    reply = api.call("client1", "GET", f"/missions/{theirs}")
    assert (reply.status_code, reply.json()["detail"]) == (403, f"mission {theirs} belongs to another client")
    assert step(api, "client1", theirs, "closed") == (403, f"mission {theirs} belongs to another client")
