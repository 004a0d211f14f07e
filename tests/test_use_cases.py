"""The mission state machines and plan checks (pure logic: no broker or store involved)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from fleetbus.schemas.missions import Geofence, MissionPlan, MissionState, Point
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.use_cases import STEPS, USE_CASES, TransitionRefused, machine_for, readiness

S = MissionState
SQUARE = {"polygon": [{"x": 0, "y": 0}, {"x": 10, "y": 0}, {"x": 10, "y": 10}, {"x": 0, "y": 10}]}


def test_the_full_use_case_has_every_state_and_survey_a_subset() -> None:
    assert USE_CASES["hazard-response"].states == list(MissionState)
    assert USE_CASES["survey"].states == [S.PLANNING, S.IN_PROGRESS, S.REVIEWING, S.CLOSED]
    for machine in USE_CASES.values():
        assert set(machine.steps) <= set(STEPS.values())


def test_an_invalid_transition_names_the_current_state_and_the_allowed_ones() -> None:
    full = machine_for("hazard-response")
    with pytest.raises(TransitionRefused) as refused:
        full.step(S.PLANNING, S.IN_PROGRESS, UserRole.SUPERVISOR)
    assert str(refused.value) == (
        "cannot go from planning to in_progress; the mission is planning; allowed next: filed, closed"
    )
    with pytest.raises(
        TransitionRefused, match="use case 'survey' has no state 'filed'; the mission is planning"
    ):
        machine_for("survey").step(S.PLANNING, S.FILED, UserRole.CLIENT)
    with pytest.raises(TransitionRefused, match=r"allowed next: none \(the mission is over\)"):
        full.step(S.CLOSED, S.PLANNING, UserRole.ADMIN)


def test_a_step_names_the_roles_that_may_take_it() -> None:
    full = machine_for("hazard-response")
    assert full.step(S.FILED, S.APPROVED, UserRole.SUPERVISOR).meaning == "approve the mission"
    with pytest.raises(TransitionRefused, match=r"filed -> approved .* is for supervisor, not client"):
        full.step(S.FILED, S.APPROVED, UserRole.CLIENT)
    assert full.step(S.IN_PROGRESS, S.REVIEWING, None).target is S.REVIEWING, "the service itself"


def test_mounting_is_allowed_once_approved_or_from_planning_without_approval() -> None:
    full, survey = machine_for("hazard-response"), machine_for("survey")
    assert [s for s in full.states if full.mountable(s)] == [S.APPROVED, S.IN_PROGRESS, S.INTERRUPTED]
    assert [s for s in survey.states if survey.mountable(s)] == [S.PLANNING, S.IN_PROGRESS]


def test_unknown_use_case() -> None:
    with pytest.raises(
        TransitionRefused, match="unknown use case 'dance'; use cases: hazard-response, survey"
    ):
        machine_for("dance")


def test_geofence_contains_its_inside_and_boundary_only() -> None:
    fence = Geofence.model_validate(SQUARE)
    assert fence.contains(Point(x=5, y=5)) and fence.contains(Point(x=10, y=3))
    assert not fence.contains(Point(x=11, y=5)) and not fence.contains(Point(x=-0.1, y=0))
    with pytest.raises(ValidationError, match="no area"):
        Geofence.model_validate({"polygon": [{"x": 0, "y": 0}, {"x": 1, "y": 1}, {"x": 2, "y": 2}]})


def test_a_plan_names_each_point_outside_the_geofence_and_unknown_names() -> None:
    with pytest.raises(ValidationError) as refused:
        MissionPlan.model_validate(
            {
                "geofence": SQUARE,
                "points_of_interest": [{"name": "lab", "x": 2, "y": 2}, {"name": "dock", "x": 12, "y": 3}],
                "itinerary": [
                    {"action": "inspect", "point_of_interest": "roof"},
                    {"action": "go", "x": 5, "y": 50},
                ],
            }
        )
    text = str(refused.value)
    assert "points_of_interest.1 'dock' (12.0, 3.0) is outside the geofence" in text
    assert "itinerary.0: no point of interest named 'roof'" in text
    assert "itinerary.1 (5.0, 50.0) is outside the geofence" in text


def test_filing_needs_a_geofence_and_a_risk_assessment() -> None:
    assert readiness(MissionPlan(), S.FILED) == [
        "the plan has no geofence",
        "the plan has no risk assessment",
    ]
    plan = MissionPlan.model_validate(
        {"geofence": SQUARE, "risk_assessment": {"level": "low", "summary": "calm"}}
    )
    assert readiness(plan, S.FILED) == [] and readiness(plan, S.IN_PROGRESS) == []
