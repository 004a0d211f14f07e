"""The HTTP API's request and reply bodies (its OpenAPI document is generated from these)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from fleetbus.api.services.account_check import Drift, DriftKind
from fleetbus.api.services.accounts import BrokerCredentials
from fleetbus.api.services.channels import BindingReport, CheckOut
from fleetbus.api.services.missions import TITLE_MOST
from fleetbus.api.services.team import TeamView
from fleetbus.schemas.identity import RobotId
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.use_cases import MissionMachine, machine_for
from fleetbus.workers.store.alerts import Alert
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.channels import ChannelChange, CheckIn, Mount
from fleetbus.workers.store.discards import Discard, DiscardCount
from fleetbus.workers.store.hazards import Hazard
from fleetbus.workers.store.missions import Mission, StateChange
from fleetbus.workers.store.sessions import Session
from fleetbus.workers.store.users import User
from fleetbus.workers.team import TeamMember


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class UserOut(BaseModel):
    name: str
    role: UserRole
    kind: str | None
    can_log_in: bool
    created_at: datetime
    created_by: str
    updated_at: datetime
    use_cases: list[str] | None = Field(
        description="the use cases the user may create missions of; null: every one (the default)"
    )

    @classmethod
    def of(cls, user: User) -> UserOut:
        return cls(
            name=user.name,
            role=user.role,
            kind=user.kind,
            can_log_in=user.password_hash is not None,
            created_at=user.created_at,
            created_by=user.created_by,
            updated_at=user.updated_at,
            use_cases=None if user.use_cases is None else list(user.use_cases),
        )


class DriftOut(BaseModel):
    """One difference between the account registry and what derives from it."""

    kind: DriftKind = Field(
        description="what differs: a broker account outside the registry, a registry user's broker "
        "account, its permissions, topic permissions or ingest shard, the team, a site's account"
    )
    name: str = Field(description="the user, robot or site it is about")
    problem: str = Field(description="what differs, for a person to read")
    repair: str = Field(description="what a repair does about it")


class RegistryCheck(BaseModel):
    """The account registry against the broker, the team and the sites."""

    repaired: list[DriftOut] = Field(description="what this request repaired (none for a check)")
    drift: list[DriftOut] = Field(description="what differs now (after a repair: what is left)")

    @classmethod
    def of(cls, repaired: list[Drift], drift: list[Drift]) -> RegistryCheck:
        return cls(
            repaired=[DriftOut(**d.as_dict()) for d in repaired],
            drift=[DriftOut(**d.as_dict()) for d in drift],
        )


class UserCreate(_In):
    name: str = Field(
        description="2-32 characters: lower-case letters, digits, '-' or '_'; also the broker account"
    )
    password: str | None = Field(None, description="at least 10 characters; none: cannot log in until set")
    role: UserRole = UserRole.INACTIVE
    kind: RobotKind | None = Field(None, description="robots only: explorer, warden or guide")


class RoleChange(_In):
    role: UserRole


class UseCasesSet(_In):
    use_cases: list[str] | None = Field(
        description="the use cases (`GET /use-cases`) the user may create missions of; null: every "
        "one, those added later too; []: none"
    )


class PasswordSet(_In):
    password: str


class PasswordChange(_In):
    current_password: str
    new_password: str


class SessionOut(BaseModel):
    id: str = Field(description="the session's id (end one with DELETE /users/me/sessions/{session_id})")
    begun_at: datetime = Field(description="when its login was")
    last_seen: datetime = Field(description="its latest request (kept to within 30 seconds)")
    expires_at: datetime = Field(
        description="when it ends by itself (FLEETBUS_API_TOKEN_MINUTES after login)"
    )
    address: str | None = Field(description="the client's address at login, when known")
    agent: str | None = Field(description="the client's User-Agent at login, when it sent one")
    current: bool = Field(description="the session of the token this request was sent with")

    @classmethod
    def of(cls, session: Session, current: Session | None = None) -> SessionOut:
        return cls(
            id=session.id,
            begun_at=session.begun_at,
            last_seen=session.last_seen,
            expires_at=session.expires_at,
            address=session.address,
            agent=session.agent,
            current=current is not None and session.id == current.id,
        )


class SessionsEnded(BaseModel):
    user: str
    ended: int = Field(
        description="how many sessions ended (their tokens and console logins are refused now)"
    )


class BrokerOut(BaseModel):
    username: str
    password: str
    vhost: str
    amqp_url: str

    @classmethod
    def of(cls, credentials: BrokerCredentials) -> BrokerOut:
        return cls(**credentials.__dict__)


class TokenOut(BaseModel):
    access_token: str
    token_type: str = "bearer"
    expires_at: datetime
    user: UserOut
    broker: BrokerOut | None = Field(
        description="the broker account: confined to resources named <user>.*; null when it may not be "
        "handed out over this connection (see broker_withheld)"
    )
    broker_withheld: str | None = Field(
        None,
        description="why the broker account was not handed out: its password goes over HTTPS only, or "
        "to a client on the API's own machine",
    )


class MissionCreate(_In):
    use_case: str = Field(description="see GET /use-cases")
    title: str = Field(min_length=1, max_length=TITLE_MOST)
    plan: MissionPlan = MissionPlan()


class TransitionIn(_In):
    to: MissionState
    note: str = Field("", max_length=500)


class MountOut(BaseModel):
    robot: str
    operator: str
    mission_id: str
    mounted_at: datetime

    @classmethod
    def of(cls, mount: Mount) -> MountOut:
        return cls(**mount.__dict__)


class CheckInOut(BaseModel):
    operator: str
    mission_id: str
    checked_in_at: datetime

    @classmethod
    def of(cls, check_in: CheckIn) -> CheckInOut:
        return cls(**check_in.__dict__)


class StateChangeOut(BaseModel):
    source: MissionState | None
    target: MissionState
    by: str
    at: datetime
    note: str

    @classmethod
    def of(cls, change: StateChange) -> StateChangeOut:
        return cls(source=change.source, target=change.target, by=change.by, at=change.at, note=change.note)


class MissionOut(BaseModel):
    mission_id: str
    use_case: str
    title: str
    owner: str
    state: MissionState
    allowed_next: list[MissionState]
    plan: MissionPlan
    created_at: datetime
    updated_at: datetime

    @classmethod
    def of(cls, mission: Mission) -> MissionOut:
        return cls(
            mission_id=mission.mission_id,
            use_case=mission.use_case,
            title=mission.title,
            owner=mission.owner,
            state=mission.state,
            allowed_next=machine_for(mission.use_case).allowed_targets(mission.state),
            plan=MissionPlan.model_validate(mission.plan),
            created_at=mission.created_at,
            updated_at=mission.updated_at,
        )


class MissionDetail(MissionOut):
    mounts: list[MountOut]
    checked_in: list[CheckInOut]
    history: list[StateChangeOut]


class CheckOutOut(BaseModel):
    operator: str
    operators_left: int
    mission: MissionOut

    @classmethod
    def of(cls, check_out: CheckOut) -> CheckOutOut:
        return cls(
            operator=check_out.operator,
            operators_left=check_out.operators_left,
            mission=MissionOut.of(check_out.mission),
        )


class MountIn(_In):
    robot: str
    mission_id: str


class ChannelChangeOut(BaseModel):
    at: datetime
    actor: str
    action: str
    mission_id: str | None
    operator: str | None
    robot: str | None
    detail: str

    @classmethod
    def of(cls, change: ChannelChange) -> ChannelChangeOut:
        return cls(**{**change.__dict__, "action": change.action.value})


class BindingReportOut(BaseModel):
    consistent: bool
    expected: list[str]
    actual: list[str]
    missing: list[str]
    unexpected: list[str]

    @classmethod
    def of(cls, report: BindingReport) -> BindingReportOut:
        return cls(
            consistent=report.consistent,
            expected=[str(b) for b in report.expected],
            actual=[str(b) for b in report.actual],
            missing=[str(b) for b in report.missing],
            unexpected=[str(b) for b in report.unexpected],
        )


class StepOut(BaseModel):
    source: MissionState
    target: MissionState
    roles: list[UserRole]
    meaning: str


class UseCaseOut(BaseModel):
    use_case: str
    description: str
    states: list[MissionState]
    steps: list[StepOut]

    @classmethod
    def of(cls, machine: MissionMachine) -> UseCaseOut:
        return cls(
            use_case=machine.use_case,
            description=machine.description,
            states=machine.states,
            steps=[
                StepOut(source=s.source, target=s.target, roles=sorted(s.roles), meaning=s.meaning)
                for s in machine.steps
            ],
        )


class EventOut(BaseModel):
    """A stored event with its provenance: the broker-validated user, exchange, routing key, mission."""

    message_id: str
    robot_id: str
    epoch: str
    seq: int
    type: str
    sent_at: datetime
    received_at: datetime
    user_id: str
    exchange: str
    routing_key: str
    mission_id: str | None
    body: dict[str, Any]
    redelivered: bool = Field(
        description="the broker had delivered it before, to a worker that did not acknowledge it (a worker "
        "or its connection lost): it may have been taken after later events of its robot"
    )

    @classmethod
    def of(cls, record: EventRecord) -> EventOut:
        return cls(**record.__dict__)


class DiscardCountOut(BaseModel):
    exchange: str
    count: int
    last_at: datetime
    last_reason: str

    @classmethod
    def of(cls, count: DiscardCount) -> DiscardCountOut:
        return cls(**count.__dict__)


class DiscardOut(BaseModel):
    exchange: str
    routing_key: str
    user_id: str | None
    message_id: str | None
    reason: str
    received_at: datetime
    headers: dict[str, str]

    @classmethod
    def of(cls, discard: Discard) -> DiscardOut:
        return cls(**discard.__dict__)


class DiscardsOut(BaseModel):
    counts: list[DiscardCountOut]
    recent: list[DiscardOut]


class TeamMemberOut(BaseModel):
    name: str
    kind: str | None
    localised: bool
    last_seen: datetime | None = Field(description="when its newest event (any type) arrived; null: never")
    stale: bool = Field(description="silent longer than FLEETBUS_STALE_AFTER_S")
    in_service: bool
    counts_for_gate: bool = Field(description="a warden in service: the hazard gate waits for it")
    service_changed_by: str | None = Field(description="who last took it out of service or put it back")
    service_changed_at: datetime | None
    outbox_dropped: dict[str, int] = Field(
        default_factory=dict,
        description="what its outbox dropped so far by type (its thinning policy), and files it set aside "
        "as unreadable (`unreadable-file`), as its newest status said",
    )

    @classmethod
    def of(cls, member: TeamMember) -> TeamMemberOut:
        return cls.model_validate(member.as_dict())


class GateOut(BaseModel):
    open: bool
    announces_to: list[str] = Field(description="the wardens in service: who announcements go to")
    closed_because: str | None


class TeamOut(BaseModel):
    robots: list[TeamMemberOut] = Field(description="the page asked for, by name")
    total: int = Field(description="robots in the team")
    gate: GateOut

    @classmethod
    def of(cls, view: TeamView) -> TeamOut:
        return cls(
            robots=[TeamMemberOut.of(member) for member in view.members],
            total=view.total,
            gate=GateOut(
                open=view.gate.open, announces_to=view.gate.wardens, closed_because=view.closed_because
            ),
        )


class HazardOut(BaseModel):
    mission_id: str
    hazard_id: int
    state: str = Field(description="held, announced, claimed, reached or cleared")
    robot_id: str = Field(description="the robot that detected it")
    description: str
    received_at: datetime
    announced_at: datetime | None
    claimed_by: str | None
    claimed_at: datetime | None
    reached_at: datetime | None
    cleared_at: datetime | None
    held_reason: str | None
    event: dict[str, Any] = Field(description="the hazard event as the robot sent it")

    @classmethod
    def of(cls, hazard: Hazard) -> HazardOut:
        description = hazard.event.get("body", {}).get("description", "")
        return cls.model_validate({**hazard.as_dict(), "description": description})


class HazardStepIn(_In):
    warden: RobotId = Field(description="the warden the step is taken for")


class HazardStepOut(BaseModel):
    hazard: HazardOut = Field(description="the hazard after the step")
    warden_told: bool = Field(description="the warden's inbox took the news of the step")
    not_told: str | None = Field(description="why the warden was not told")


class AlertOut(BaseModel):
    """One occurrence of a condition the operators acknowledge."""

    id: int = Field(description="what `POST /alerts/{alert_id}/acknowledge` and `fleetbus alerts ack` take")
    kind: str = Field(
        description="hazard-announced, hazard-unclaimed, battery-low, robot-stale, uplink-near-full or "
        "dead-letters-growing"
    )
    subject: str = Field(
        description="what it is about: `robot NAME`, `hazard MISSION/ID`, `site NAME`, `queue NAME`"
    )
    detail: str
    since: datetime = Field(description="when the condition began, as the store says (else when first seen)")
    raised_at: datetime
    ended_at: datetime | None = Field(description="when the condition was seen to end; null while it holds")
    acknowledged_by: str | None
    acknowledged_at: datetime | None = Field(description="UTC")

    @classmethod
    def of(cls, alert: Alert) -> AlertOut:
        return cls(
            id=alert.id,
            kind=alert.kind,
            subject=alert.subject,
            detail=alert.detail,
            since=alert.since,
            raised_at=alert.raised_at,
            ended_at=alert.ended_at,
            acknowledged_by=alert.acknowledged_by,
            acknowledged_at=alert.acknowledged_at,
        )


class AlertsOut(BaseModel):
    unacknowledged: list[AlertOut] = Field(description="every alert not acknowledged yet, oldest first")
    acknowledged: list[AlertOut] = Field(
        description="with `acknowledged=true`: the last acknowledged (FLEETBUS_ALERTS_ACKNOWLEDGED_SHOWN), "
        "the last first; else empty"
    )
