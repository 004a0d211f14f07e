"""The recording over HTTP: queries on any type, a robot's timeline, a message's trace, the
performance evaluation and the recording's growth. Each calls the plain functions of
:mod:`fleetbus.workers.recorder.queries` (the command line calls the same ones).

Fault analysis reads every robot's traffic: administrators, supervisors and operators. The
evaluation and the growth are figures, not traffic: planners may read them too.
"""

from __future__ import annotations

import base64
from datetime import datetime, timedelta, timezone
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query
from pydantic import BaseModel, BeforeValidator, Field

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.openapi import refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import BadRequest
from fleetbus.api.services.recording import OutcomeStats, RecordedMessage
from fleetbus.limits import read_iso_time
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.roles import EVALUATORS, WATCHERS
from fleetbus.schemas.routing import NOTIFY_EXCHANGE, inbox_queue
from fleetbus.workers.recorder.capture import KNOWN_TYPES
from fleetbus.workers.recorder.growth import LONGEST_BUCKET, SHORTEST_BUCKET
from fleetbus.workers.recorder.queries import LIMIT_MAX, SEARCH_LIMIT, TIMELINE_LIMIT

router = APIRouter(prefix="/recording", tags=["recording"])
Analyst = Annotated[User, Depends(require_role(*WATCHERS))]
Evaluator = Annotated[User, Depends(require_role(*EVALUATORS))]
Limit = Annotated[int, Query(ge=1, le=LIMIT_MAX)]


def _time_in_query(value: Any) -> Any:
    """:func:`~fleetbus.limits.read_iso_time`, as the document's ``date-time`` says: pydantic
    alone would also take a number, as seconds since 1970."""
    if not isinstance(value, str):
        return value
    try:
        return read_iso_time(value)
    except ValueError:
        raise ValueError(f"{value!r} is not an ISO 8601 time, such as 2026-11-27T08:00:00Z") from None


MINUTE = timedelta(minutes=1)
#: A time in a query.
Moment = Annotated[datetime, BeforeValidator(_time_in_query)]


class RecordOut(BaseModel):
    """A recorded message: its body as received and what the recorder knows of it."""

    type: str
    recorded_at: datetime
    known: bool
    problem: str | None
    user_id: str | None
    robot_id: str | None
    exchange: str
    routing_key: str
    message_id: str | None
    mission_id: str | None
    sent_at: datetime | None
    seq: int | None
    size: int
    headers: dict[str, Any]
    document: Any
    raw_base64: str | None

    @classmethod
    def of(cls, record: RecordedMessage) -> RecordOut:
        return cls(
            **{name: getattr(record, name) for name in cls.model_fields if hasattr(record, name)},
            headers=record.properties.get("headers") or {},
            raw_base64=base64.b64encode(record.raw).decode() if record.raw else None,
        )


class TypeOut(BaseModel):
    type: str
    known: bool
    records: int
    bytes: int
    first: datetime | None
    last: datetime | None
    field_indexes: list[list[str]]


class TimelineEntryOut(BaseModel):
    sent: bool
    """True for what the robot sent, False for what it was sent."""
    record: RecordOut


class TimelineOut(BaseModel):
    robot_id: str
    truncated: bool
    entries: list[TimelineEntryOut]


class RouteOut(BaseModel):
    queue: str
    via: list[str]
    consumers: list[str] = Field(description="the consuming accounts the broker has reported")
    consumers_unreported: int = Field(
        0, description="consumers whose account the broker's statistics have not reported yet (seconds)"
    )


class TracedOut(BaseModel):
    record: RecordOut
    routes: list[RouteOut]


class TraceOut(BaseModel):
    message_id: str
    records: list[TracedOut]
    stored_epoch: str | None
    stored_seq: int | None
    stored_at: datetime | None
    stored_mission_id: str | None
    caused: list[TracedOut]


class OutcomeOut(BaseModel):
    name: str
    successes: int
    failures: int
    success_rate: float
    mean_duration: float
    std_duration: float

    @classmethod
    def of(cls, stats: OutcomeStats) -> OutcomeOut:
        return cls(**stats.__dict__, success_rate=stats.success_rate)


class GrowthOut(BaseModel):
    start: datetime
    end: datetime
    database_bytes: int
    inserted: int
    megabytes_per_minute: float
    inserts_per_minute: float


@router.get("/types", response_model=list[TypeOut])
async def recorded_types(user: Analyst, svc: ServiceDep) -> list[TypeOut]:
    """Every recorded type: known to fleetbus or not, how much of it, from when to when, its field indexes."""
    out = []
    for recorded in await svc.recording_queries.type_views():
        summary = recorded.summary
        indexes = [list(paths) for paths in recorded.field_indexes]
        out.append(TypeOut(**summary.__dict__, known=recorded.name in KNOWN_TYPES, field_indexes=indexes))
    return out


@router.get("/records/{message_type}", response_model=list[RecordOut], responses=refusals(BadRequest))
async def records(
    message_type: str,
    user: Analyst,
    svc: ServiceDep,
    where: Annotated[
        list[str] | None, Query(description="FIELD=VALUE, or != < <= > >= ~; all must hold")
    ] = None,
    robot: str | None = None,
    mission: str | None = None,
    since: Moment | None = None,
    until: Moment | None = None,
    limit: Limit = SEARCH_LIMIT,
    latest: bool = False,
) -> list[RecordOut]:
    """Recorded messages of a type meeting every condition, oldest first (the newest ``limit``);
    ``latest`` gives only the newest, as in "the latest failed grab of a bottle"."""
    found = await svc.recording_queries.find(
        message_type,
        svc.recording_queries.conditions(where or [], message_type),
        robot_id=robot,
        mission_id=mission,
        since=since,
        until=until,
        limit=1 if latest else limit,
        newest_first=True,
    )
    return [RecordOut.of(record) for record in reversed(found)]


@router.get("/timeline/{robot}", response_model=TimelineOut)
async def robot_timeline(
    robot: str,
    user: Analyst,
    svc: ServiceDep,
    since: Moment | None = None,
    until: Moment | None = None,
    limit: Limit = TIMELINE_LIMIT,
) -> TimelineOut:
    """What the robot sent and was sent in the window (default: the last hour), every type in time order."""
    try:
        validate_name(robot)
    except ValueError as error:
        raise HTTPException(422, detail=str(error)) from None
    start = since or datetime.now(timezone.utc) - timedelta(hours=1)
    routes = await svc.route_map()
    inbound = routes.keys_into(inbox_queue(robot), NOTIFY_EXCHANGE)
    result = await svc.recording_queries.timeline(robot, start, until, inbound=inbound, limit=limit)
    return TimelineOut(
        robot_id=robot,
        truncated=result.truncated,
        entries=[TimelineEntryOut(sent=e.sent, record=RecordOut.of(e.record)) for e in result.entries],
    )


@router.get("/trace/{message_id}", response_model=TraceOut)
async def trace_message(message_id: str, user: Analyst, svc: ServiceDep) -> TraceOut:
    """Where a message came from (broker-validated user, exchange, routing key, mission, times), what
    the service made of it, the queues that receive it and their consumers now, what it caused."""
    result = await svc.recording_queries.trace(message_id, await svc.route_map())
    if not result.records:
        raise HTTPException(404, detail=f"message {message_id!r} was never recorded")

    def traced(record: RecordedMessage) -> TracedOut:
        routes = [
            RouteOut(
                queue=r.queue,
                via=list(r.via),
                consumers=sorted({c.user for c in r.consumers if c.user is not None}),
                consumers_unreported=sum(c.user is None for c in r.consumers),
            )
            for r in result.routes.get(record.key, [])
        ]
        return TracedOut(record=RecordOut.of(record), routes=routes)

    stored = result.stored
    return TraceOut(
        message_id=message_id,
        records=[traced(r) for r in result.records],
        stored_epoch=stored.epoch if stored else None,
        stored_seq=stored.seq if stored else None,
        stored_at=stored.received_at if stored else None,
        stored_mission_id=stored.mission_id if stored else None,
        caused=[traced(r) for r in result.caused],
    )


@router.get("/evaluation", response_model=list[OutcomeOut])
async def evaluation(
    user: Evaluator,
    svc: ServiceDep,
    since: Moment | None = None,
    until: Moment | None = None,
    robot: str | None = None,
) -> list[OutcomeOut]:
    """Per behaviour: successes, failures, success rate, mean and standard deviation of the duration,
    computed by the database."""
    stats = await svc.recording_queries.evaluate(since, until, robot_id=robot)
    return [OutcomeOut.of(s) for s in stats]


@router.get("/growth", response_model=list[GrowthOut])
async def recording_growth(
    user: Evaluator,
    svc: ServiceDep,
    since: Moment | None = None,
    every_minutes: Annotated[float, Query(ge=SHORTEST_BUCKET / MINUTE, le=LONGEST_BUCKET / MINUTE)] = 1,
) -> list[GrowthOut]:
    """The recording's growth (MB per minute) and inserts per minute, one row per ``every_minutes``."""
    start = since or datetime.now(timezone.utc) - timedelta(hours=1)
    rows = await svc.recording_queries.growth(start, timedelta(minutes=every_minutes))
    return [
        GrowthOut(
            start=r.start,
            end=r.end,
            database_bytes=r.database_bytes,
            inserted=r.inserted,
            megabytes_per_minute=r.megabytes_per_minute,
            inserts_per_minute=r.inserts_per_minute,
        )
        for r in rows
    ]
