"""The recording from the command line, against the real broker, worker and recorder: the
reference's two queries, a robot's timeline, a message's trace, the performance evaluation."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from fleetbus.broker.accounts import RECORDER_USER, SERVICE_USER
from fleetbus.broker.routes import Consumer, RouteMap
from fleetbus.cli.commands.trace import _consumers
from fleetbus.schemas.routing import EXPRESS_QUEUE, RECORDER_QUEUE, EventType, RobotKind
from tests.factories import hazard
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

GRABS = [  # name, object, success, duration
    ("grab", "bottle", False, 12.0),
    ("grab", "bottle", True, 10.0),
    ("grab", "bottle", False, 14.0),
    ("grab", "cup", False, 3.0),
    ("place", "bottle", True, 5.0),
]
FRAMES = [
    ("/kinect/depth", "/object/bottle"),
    ("/kinect/depth", "/object/bottle"),
    ("/kinect/depth", "/object/cup"),
    ("/kinect/depth", "/object/bottle"),
    ("/rx28/tilt", "/object/bottle"),
    ("/kinect/depth", "/object/bottle"),
]


def lines(result: Any) -> list[dict[str, Any]]:
    assert result.returncode == 0, result.stderr
    return [json.loads(line) for line in result.stdout.splitlines()]


@pytest.fixture
def scene(bus: Bus) -> Iterator[dict[str, Any]]:
    """A warden, and a robot that grabs, detects a hazard, sends transforms and one bad hazard;
    the worker and the recorder run through the whole test."""
    warden = bus.add("cli-warden", kind=RobotKind.WARDEN)
    herb = bus.add("cli-herb", kind=RobotKind.EXPLORER)
    with bus.worker(), bus.recorder(), bus.robot(warden) as w, bus.robot(herb) as robot:
        w.publish(EventType.LOCALISATION, {"localised": True})
        for name, obj, success, duration in GRABS:
            body = {"name": name, "object": obj, "success": success, "duration_s": duration}
            robot.publish(EventType.BEHAVIOUR, body)
        detected = robot.publish(EventType.HAZARD, hazard())
        for i, (frame, child) in enumerate(FRAMES):
            tf = {"frame": frame, "child_frame": child, "translation": {"x": i, "y": 0, "z": 0}}
            bus.publish_raw(herb, "cli-herb.tf", json.dumps(tf).encode(), message_id=f"tf-{i}")
        bad = json.dumps({**hazard(), "pose": {"x": "left"}}).encode()
        bus.publish_raw(herb, "cli-herb.hazard", bad, message_id="bad-hazard")
        wait_for(lambda: len(bus.recorded("dead_letter")) == len(FRAMES) + 1, what="refusals recorded")
        wait_for(lambda: bus.recorded("notification"), what="the hazard's notification recorded")
        wait_for(lambda: len(bus.recorded("behaviour")) == len(GRABS), what="behaviours recorded")
        yield {"hazard": detected, "transforms": bus.recorded("tf")}


def test_the_latest_failed_grab_of_a_bottle(bus: Bus, scene: dict[str, Any]) -> None:
    where = ["-w", "name=grab", "-w", "object=bottle", "-w", "success=false"]
    [latest] = lines(fleetbus(bus, "query", "behaviour", *where, "--latest", "--json"))
    assert latest["body"] == {
        "name": "grab",
        "object": "bottle",
        "success": False,
        "duration_s": 14.0,
        "error": None,
        "started_at": None,
    }
    assert latest["__recorded"]["user_id"] == "cli-herb" and latest["__recorded"]["known"] is True
    every = lines(fleetbus(bus, "query", "behaviour", *where, "--json"))
    assert [r["body"]["duration_s"] for r in every] == [12.0, 14.0], "oldest first"
    table = fleetbus(bus, "query", "behaviour", *where)
    assert "2 behaviour events" in table.stdout and "cli-herb" in table.stdout
    types = lines(fleetbus(bus, "recorder", "types", "--json"))
    behaviour = next(t for t in types if t["type"] == "behaviour")
    assert ["body.name", "body.object", "body.success"] in behaviour["field_indexes"]


def test_all_transforms_between_two_frames_in_a_time_range(bus: Bus, scene: dict[str, Any]) -> None:
    recorded = scene["transforms"]
    since, until = recorded[1].recorded_at.isoformat(), recorded[5].recorded_at.isoformat()
    found = lines(
        fleetbus(
            bus,
            "query",
            "tf",
            "-w",
            "frame=/kinect/depth",
            "-w",
            "child_frame=/object/bottle",
            "--since",
            since,
            "--until",
            until,
            "--json",
        )
    )
    assert [t["translation"]["x"] for t in found] == [1, 3]
    assert all(t["__recorded"]["known"] is False for t in found), "tf has no fleetbus schema"
    types = {t["type"]: t for t in lines(fleetbus(bus, "recorder", "types", "--json"))}
    assert types["tf"]["records"] == len(FRAMES) and types["tf"]["known"] is False


def test_a_bad_query_names_its_problem(bus: Bus) -> None:
    for where, problem in (
        ("frame", "write FIELD=VALUE"),
        ("a..b=1", "invalid field"),
        ("x>true", "order by"),
    ):
        result = fleetbus(bus, "query", "tf", "-w", where)
        assert result.returncode == 2 and problem in result.stderr, result.stderr
    assert "nothing recorded of type 'nothing'" in fleetbus(bus, "query", "nothing").stdout
    # a name no robot can have: refused as the HTTP API refuses it (422), not an empty answer
    named = fleetbus(bus, "query", "hazard", "--robot", "Robot.1")
    assert named.returncode == 2 and "robot: invalid name 'Robot.1'" in named.stderr, named.stderr
    retention = fleetbus(bus, "recorder", "run", "--keep", "status=7x")
    assert retention.returncode == 2 and "retention 'status=7x'" in retention.stderr


def test_a_robots_timeline_merges_every_type_in_order(bus: Bus, scene: dict[str, Any]) -> None:
    herb = lines(fleetbus(bus, "timeline", "cli-herb", "--since", "10m", "--json"))
    kinds = [(e["__recorded"]["type"], e["sent"]) for e in herb]
    assert kinds.count(("behaviour", True)) == len(GRABS) and kinds.count(("tf", True)) == len(FRAMES)
    assert ("hazard", True) in kinds and kinds.count(("dead_letter", True)) == len(FRAMES) + 1
    times = [e["__recorded"]["at"] for e in herb]
    assert times == sorted(times)
    warden = lines(fleetbus(bus, "timeline", "cli-warden", "--json"))
    assert [(e["__recorded"]["type"], e["sent"]) for e in warden] == [
        ("localisation", True),
        ("notification", False),
    ]
    assert warden[1]["hazard_id"] == 1 and warden[1]["event"]["robot_id"] == "cli-herb"
    table = fleetbus(bus, "timeline", "cli-herb", "--since", "10m")
    assert "refused (schema)" in table.stdout and "tf (unknown)" in table.stdout


def test_trace_shows_where_a_message_came_from_and_who_received_it(bus: Bus, scene: dict[str, Any]) -> None:
    detected = scene["hazard"]

    def consumers_reported() -> bool:
        """The management API lists a consumer before its channel's details (its user), seconds apart."""
        reported = {
            consumer["queue"]["name"]
            for consumer in bus.api.list_consumers(bus.vhost)
            if (consumer.get("channel_details") or {}).get("user")
        }
        return reported >= {EXPRESS_QUEUE, RECORDER_QUEUE}

    wait_for(consumers_reported, what="the management API to report the consumers' users")
    result = fleetbus(bus, "trace", str(detected.message_id), "--json")
    table = fleetbus(bus, "trace", str(detected.message_id))
    assert result.returncode == 0 and "no broker" not in result.stderr, result.stderr
    traced = json.loads(result.stdout)
    [origin] = traced["records"]
    recorded = origin["__recorded"]
    assert (recorded["user_id"], recorded["exchange"], recorded["routing_key"]) == (
        "cli-herb",
        "cli-herb.events",
        "cli-herb.hazard",
    )
    assert traced["stored"]["seq"] == detected.seq
    routes = {r["queue"]: r for r in origin["routes"]}
    assert set(routes) == {EXPRESS_QUEUE, RECORDER_QUEUE}, "a hazard takes the express lane"
    assert routes[EXPRESS_QUEUE]["via"] == ["cli-herb.events", "fleetbus.ingest", "fleetbus.ingest.shards"]
    assert [c["user"] for c in routes[EXPRESS_QUEUE]["consumers"]] == [SERVICE_USER]
    assert [c["user"] for c in routes[RECORDER_QUEUE]["consumers"]] == [RECORDER_USER]
    [note] = traced["caused"]
    assert note["__recorded"]["routing_key"] == "notify.hazard"
    assert "cli-warden.inbox" in {r["queue"] for r in note["routes"]}
    assert "published by" in table.stdout and "cli-herb.events →" in table.stdout
    assert f"as epoch {detected.epoch} seq {detected.seq}" in table.stdout, "the express lane stored it"

    refused = json.loads(fleetbus(bus, "trace", "bad-hazard", "--json").stdout)
    assert {r["__recorded"]["type"] for r in refused["records"]} == {"hazard", "dead_letter"}
    assert refused["stored"] is None
    missing = fleetbus(bus, "trace", "no-such-message")
    assert missing.returncode == 1 and "never recorded" in missing.stderr


def test_performance_evaluation_per_behaviour(bus: Bus, scene: dict[str, Any], tmp_path: Path) -> None:
    plot = tmp_path / "evaluation.png"
    stats = {
        s["name"]: s for s in lines(fleetbus(bus, "evaluate", "--since", "1h", "--json", "--plot", str(plot)))
    }
    grab = stats["grab"]
    assert (grab["successes"], grab["failures"], grab["success_rate"]) == (1, 3, 0.25)
    assert grab["mean_duration"] == pytest.approx(9.75) and grab["std_duration"] == pytest.approx(4.145780987)
    assert (stats["place"]["successes"], stats["place"]["failures"]) == (1, 0)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    only_herb = lines(fleetbus(bus, "evaluate", "--robot", "cli-warden", "--json"))
    assert only_herb == []
    table = fleetbus(bus, "evaluate")
    assert "25.0%" in table.stdout and "9.750" in table.stdout


def test_trace_says_plainly_when_the_broker_has_not_reported_a_consumers_user() -> None:
    """The management API lists a consumer seconds before its channel's details: no bare '?'."""
    listed = {"channel_details": [], "queue": {"name": RECORDER_QUEUE}}
    reported = {
        "channel_details": {"user": RECORDER_USER, "connection_name": "c1"},
        "queue": {"name": RECORDER_QUEUE},
    }

    class Listing:
        def list_exchanges(self, vhost: str) -> list[dict[str, Any]]:
            return [{"name": "fleetbus.ingest", "type": "topic"}]

        def list_bindings(self, vhost: str) -> list[dict[str, Any]]:
            binding = {"source": "fleetbus.ingest", "destination": RECORDER_QUEUE}
            return [{**binding, "destination_type": "queue", "routing_key": "#"}]

        def __init__(self, consumers: list[dict[str, Any]]) -> None:
            self.list_consumers = lambda vhost: consumers

    [route] = RouteMap.from_management(Listing([listed]), "/").routes("fleetbus.ingest", "r.hazard")  # type: ignore[arg-type]
    assert route.consumers == (Consumer(None, None),)
    assert _consumers(route) == "a consumer (user not reported by the broker yet)"
    [route] = RouteMap.from_management(Listing([reported]), "/").routes("fleetbus.ingest", "r.hazard")  # type: ignore[arg-type]
    assert _consumers(route) == RECORDER_USER
