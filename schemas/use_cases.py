"""Mission life cycles: one finite state machine per use case, each a subset of one table of steps.

Every step (source state to target state) is defined once, with the roles that may take it and
what it means. A use case lists the steps it uses: ``hazard-response`` uses every state, while
``survey`` (like the reference's RoboVaaS) has no filed, approved or interrupted state and starts
straight from planning. :meth:`MissionMachine.refusal` words an invalid request with the current
state and the steps allowed from it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole

S = MissionState
R = UserRole


@dataclass(frozen=True)
class Step:
    source: MissionState
    target: MissionState
    roles: frozenset[UserRole]
    meaning: str


def _step(source: MissionState, target: MissionState, roles: Iterable[UserRole], meaning: str) -> Step:
    return Step(source, target, frozenset(roles), meaning)


#: Every step any use case may take. ``in_progress -> reviewing`` is also taken by the service
#: itself when the mission's last operator checks out.
STEPS: dict[tuple[MissionState, MissionState], Step] = {
    (s.source, s.target): s
    for s in (
        _step(S.PLANNING, S.FILED, {R.CLIENT, R.PLANNER}, "file the risk assessment for approval"),
        _step(S.FILED, S.PLANNING, {R.SUPERVISOR, R.PLANNER}, "send the plan back for changes"),
        _step(S.FILED, S.APPROVED, {R.SUPERVISOR}, "approve the mission"),
        _step(S.APPROVED, S.IN_PROGRESS, {R.SUPERVISOR}, "start: the supervisor checks the mission in"),
        _step(S.PLANNING, S.IN_PROGRESS, {R.SUPERVISOR}, "start: the supervisor checks the mission in"),
        _step(S.IN_PROGRESS, S.INTERRUPTED, {R.SUPERVISOR, R.OPERATOR}, "interrupt: something unplanned"),
        _step(S.INTERRUPTED, S.IN_PROGRESS, {R.SUPERVISOR}, "resume after an interruption"),
        _step(S.IN_PROGRESS, S.REVIEWING, {R.SUPERVISOR}, "end operations and review the results"),
        _step(S.INTERRUPTED, S.REVIEWING, {R.SUPERVISOR}, "end operations and review the results"),
        _step(S.REVIEWING, S.CLOSED, {R.CLIENT, R.SUPERVISOR}, "accept or reject the results"),
        _step(S.PLANNING, S.CLOSED, {R.CLIENT, R.PLANNER}, "cancel before filing"),
        _step(S.FILED, S.CLOSED, {R.CLIENT, R.SUPERVISOR}, "cancel or refuse"),
        _step(S.APPROVED, S.CLOSED, {R.CLIENT, R.SUPERVISOR}, "cancel before the start"),
    )
}

#: States in which operators may mount robots for the mission (data is recorded only after
#: check-in, which needs the mission in progress).
MOUNTABLE = frozenset({S.APPROVED, S.IN_PROGRESS, S.INTERRUPTED})
CHECK_IN_STATES = frozenset({S.IN_PROGRESS})


class TransitionRefused(ValueError):
    """A step the machine does not have from the current state, or a role that may not take it."""


class InvalidTransition(TransitionRefused):
    """The machine has no such step from the current state (or no such use case)."""


class RoleNotAllowed(TransitionRefused):
    """The step exists, but not for the caller's role."""


@dataclass(frozen=True)
class MissionMachine:
    use_case: str
    description: str
    steps: tuple[Step, ...]

    @property
    def states(self) -> list[MissionState]:
        present = {S.PLANNING} | {s.source for s in self.steps} | {s.target for s in self.steps}
        return sorted(present, key=lambda state: state.rank)

    def steps_from(self, state: MissionState) -> list[Step]:
        return [step for step in self.steps if step.source is state]

    def allowed_targets(self, state: MissionState) -> list[MissionState]:
        return [step.target for step in self.steps_from(state)]

    def mountable(self, state: MissionState) -> bool:
        """Operators may mount robots: approved and later, or from planning when there is no approval."""
        if S.APPROVED not in self.states and state is S.PLANNING:
            return True
        return state in MOUNTABLE

    def step(self, state: MissionState, target: MissionState, role: UserRole | None) -> Step:
        """The step from ``state`` to ``target`` for ``role`` (``None``: the service itself)."""
        found = next((s for s in self.steps_from(state) if s.target is target), None)
        if found is None:
            raise InvalidTransition(self.refusal(state, target))
        if role is not None and role not in found.roles:
            who = " or ".join(sorted(r.value for r in found.roles))
            raise RoleNotAllowed(
                f"{state.value} -> {target.value} ({found.meaning}) is for {who}, not {role.value}"
            )
        return found

    def refusal(self, state: MissionState, target: MissionState) -> str:
        allowed = ", ".join(t.value for t in self.allowed_targets(state)) or "none (the mission is over)"
        if target not in self.states:
            return (
                f"use case {self.use_case!r} has no state {target.value!r}; "
                f"the mission is {state.value}; allowed next: {allowed}"
            )
        return (
            f"cannot go from {state.value} to {target.value}; "
            f"the mission is {state.value}; allowed next: {allowed}"
        )


def readiness(plan: MissionPlan, target: MissionState) -> list[str]:
    """What the plan lacks before the mission may enter ``target`` (filed or started)."""
    missing: list[str] = []
    if target in (S.FILED, S.IN_PROGRESS) and plan.geofence is None:
        missing.append("the plan has no geofence")
    if target is S.FILED and plan.risk_assessment is None:
        missing.append("the plan has no risk assessment")
    return missing


def _machine(
    use_case: str, description: str, pairs: Iterable[tuple[MissionState, MissionState]]
) -> MissionMachine:
    return MissionMachine(use_case, description, tuple(STEPS[pair] for pair in pairs))


USE_CASES: dict[str, MissionMachine] = {
    machine.use_case: machine
    for machine in (
        _machine(
            "hazard-response",
            "The full life cycle: the risk assessment is filed and approved before the start; "
            "operations can be interrupted and resumed.",
            [
                (S.PLANNING, S.FILED),
                (S.FILED, S.PLANNING),
                (S.FILED, S.APPROVED),
                (S.APPROVED, S.IN_PROGRESS),
                (S.IN_PROGRESS, S.INTERRUPTED),
                (S.INTERRUPTED, S.IN_PROGRESS),
                (S.IN_PROGRESS, S.REVIEWING),
                (S.INTERRUPTED, S.REVIEWING),
                (S.REVIEWING, S.CLOSED),
                (S.PLANNING, S.CLOSED),
                (S.FILED, S.CLOSED),
                (S.APPROVED, S.CLOSED),
            ],
        ),
        _machine(
            "survey",
            "Relaxed safety procedures (no aerial robots): no filing, approval or interruption; "
            "the supervisor starts the mission straight from planning.",
            [
                (S.PLANNING, S.IN_PROGRESS),
                (S.IN_PROGRESS, S.REVIEWING),
                (S.REVIEWING, S.CLOSED),
                (S.PLANNING, S.CLOSED),
            ],
        ),
    )
}


def machine_for(use_case: str) -> MissionMachine:
    try:
        return USE_CASES[use_case]
    except KeyError:
        raise InvalidTransition(
            f"unknown use case {use_case!r}; use cases: {', '.join(sorted(USE_CASES))}"
        ) from None
