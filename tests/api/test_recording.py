"""The recording over HTTP, on the real app, broker, worker and recorder, with each store: the
reference's two queries, a timeline, a trace and the evaluation."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlencode

import pytest

from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EventType, RobotKind
from tests.api.support import Api, running_api
from tests.factories import hazard
from tests.support import Bus, wait_for

OUTCOMES = [("grab", "bottle", False, 12.0), ("grab", "bottle", True, 10.0), ("grab", "bottle", False, 14.0)]


@pytest.fixture
def scene(stored_bus: Bus) -> Iterator[tuple[Api, dict[str, Any]]]:
    bus = stored_bus
    warden = bus.add("http-warden", kind=RobotKind.WARDEN)
    herb = bus.add("http-herb", kind=RobotKind.EXPLORER)
    with running_api(bus) as api, bus.worker(), bus.recorder():
        api.user("super1", UserRole.SUPERVISOR)
        api.user("planner1", UserRole.PLANNER)
        with bus.robot(warden) as w, bus.robot(herb) as robot:
            w.publish(EventType.LOCALISATION, {"localised": True})
            for name, obj, success, duration in OUTCOMES:
                body = {"name": name, "object": obj, "success": success, "duration_s": duration}
                robot.publish(EventType.BEHAVIOUR, body)
            detected = robot.publish(EventType.HAZARD, hazard())
        for i, child in enumerate(["/object/bottle", "/object/cup", "/object/bottle"]):
            tf = json.dumps({"frame": "/kinect/depth", "child_frame": child, "i": i}).encode()
            bus.publish_raw(herb, "http-herb.tf", tf, message_id=f"tf-{i}")
        wait_for(lambda: bus.recorded("notification"), what="the hazard's notification recorded")
        wait_for(lambda: len(bus.recorded("tf")) == 3, what="the transforms recorded")
        yield api, {"hazard": detected, "transforms": bus.recorded("tf")}


def get(api: Api, who: str, path: str, **query: Any) -> Any:
    reply = api.call(who, "GET", f"{path}?{urlencode(query, doseq=True)}" if query else path)
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_the_reference_queries_over_http(scene: tuple[Api, dict[str, Any]]) -> None:
    api, seen = scene
    where = ["name=grab", "object=bottle", "success=false"]
    [latest] = get(api, "super1", "/recording/records/behaviour", where=where, latest="true")
    assert latest["document"]["body"]["duration_s"] == 14.0 and latest["user_id"] == "http-herb"
    transforms = seen["transforms"]
    found = get(
        api,
        "super1",
        "/recording/records/tf",
        where=["frame=/kinect/depth", "child_frame=/object/bottle"],
        since=transforms[0].recorded_at.isoformat(),
        until=transforms[2].recorded_at.isoformat(),
    )
    assert [t["document"]["i"] for t in found] == [0], "the window ends before the third"
    assert found[0]["known"] is False and found[0]["exchange"] == "http-herb.events"
    bad = api.call("super1", "GET", "/recording/records/tf?where=frame")
    assert bad.status_code == 422 and "write FIELD=VALUE" in bad.json()["detail"]
    named = api.call("super1", "GET", "/recording/records/tf?robot=Robot.1")
    assert named.status_code == 422 and "robot: invalid name" in named.json()["detail"]
    types = {t["type"]: t for t in get(api, "super1", "/recording/types")}
    assert types["tf"]["known"] is False and types["tf"]["records"] == 3
    assert ["child_frame", "frame"] in types["tf"]["field_indexes"], "the query made its index"


def test_timeline_trace_and_evaluation_over_http(scene: tuple[Api, dict[str, Any]]) -> None:
    api, seen = scene
    warden = get(api, "super1", "/recording/timeline/http-warden")
    assert [(e["record"]["type"], e["sent"]) for e in warden["entries"]] == [
        ("localisation", True),
        ("notification", False),
    ]
    detected = seen["hazard"]
    traced = get(api, "super1", f"/recording/trace/{detected.message_id}")
    [origin] = traced["records"]
    assert (origin["record"]["user_id"], origin["record"]["routing_key"]) == ("http-herb", "http-herb.hazard")
    assert traced["stored_seq"] == detected.seq
    assert {r["queue"] for r in origin["routes"]} == {"fleetbus.ingest.express", "fleetbus.recorder"}
    assert "http-warden.inbox" in {r["queue"] for r in traced["caused"][0]["routes"]}
    assert api.call("super1", "GET", "/recording/trace/nothing-like-it").status_code == 404
    [grab] = get(api, "planner1", "/recording/evaluation", since="2000-01-01T00:00:00")
    assert (grab["name"], grab["successes"], grab["failures"]) == ("grab", 1, 2)
    assert grab["mean_duration"] == 12.0 and grab["std_duration"] == pytest.approx(1.632993162)
