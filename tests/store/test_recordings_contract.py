"""One contract for the recording, on SQLite and on MongoDB: the same records, the same answers."""

from __future__ import annotations

import statistics
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from typing import Any

import pytest

from fleetbus.workers.recorder.retention import SAMPLES, RetentionSweeper, samples_retention
from fleetbus.workers.store.recordings import (
    Condition,
    Op,
    OutcomeFields,
    RecordedMessage,
    RecordingError,
    RecordingStore,
    RecordQuery,
    StorageSample,
)

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)


def rec(
    key: str,
    document: Any = None,
    *,
    type: str = "tf",
    at: float = 0.0,
    robot: str | None = "herb",
    **fields: Any,
) -> RecordedMessage:
    """A record of ``type`` recorded ``at`` seconds after T0."""
    return RecordedMessage(
        key=key,
        type=type,
        recorded_at=T0 + timedelta(seconds=at),
        exchange=f"{robot}.events" if robot else "fleetbus.notify",
        routing_key=f"{robot}.{type}",
        user_id=robot,
        robot_id=robot,
        document=document if document is not None else {"n": key},
        **{"size": 100, **fields},
    )


def keys(records: list[RecordedMessage]) -> list[str]:
    return [r.key for r in records]


async def test_every_field_round_trips_exactly(recording: RecordingStore) -> None:
    full = rec(
        "k1",
        {"frame": "/rx28/tilt", "translation": {"x": 0.1, "y": -2, "z": 3e-9}, "list": [1, "a", None, True]},
        message_id="m-1",
        mission_id="mission-β",
        sent_at=T0 - timedelta(microseconds=7),
        seq=41,
        known=False,
        properties={"content_type": "application/json", "headers": {"x": "ünï", "n": 3}},
    )
    raw = replace(
        rec("k2", robot=None, problem="not JSON: bad byte", size=4), document=None, raw=b"\x00\xffok"
    )
    results = await recording.write_recorded([full, raw])
    assert [r.inserted for r in results] == [True, True]
    assert await recording.find_recorded(RecordQuery("tf")) == [full, raw]


async def test_writes_are_idempotent_on_the_key(recording: RecordingStore) -> None:
    first = await recording.write_recorded([rec("a"), rec("b"), rec("a", at=5)])
    assert [r.inserted for r in first] == [True, True, False]
    again = await recording.write_recorded([rec("b", {"changed": True}), rec("c")])
    assert [r.inserted for r in again] == [False, True]
    found = await recording.find_recorded(RecordQuery("tf"))
    assert keys(found) == ["a", "b", "c"] and found[1].document == {"n": "b"}, "the first copy stays"


async def test_one_collection_per_type_made_on_first_sight(recording: RecordingStore) -> None:
    assert await recording.recorded_types() == []
    await recording.write_recorded([rec("1", type="tf"), rec("2", type="behaviour"), rec("3", type="tf")])
    assert await recording.recorded_types() == ["behaviour", "tf"]
    assert keys(await recording.find_recorded(RecordQuery("behaviour"))) == ["2"]
    assert await recording.find_recorded(RecordQuery("never_seen")) == []
    summary = await recording.type_summary("tf")
    assert (summary.records, summary.bytes, summary.first, summary.last) == (2, 200, T0, T0)
    assert (await recording.type_summary("never_seen")).records == 0


async def test_names_that_could_abuse_a_query_are_refused(recording: RecordingStore) -> None:
    with pytest.raises(RecordingError, match="invalid type"):
        await recording.find_recorded(RecordQuery('tf"; DROP TABLE x; --'))
    with pytest.raises(RecordingError, match="invalid field"):
        Condition("frame') OR 1=1 --", Op.EQ, "x")
    with pytest.raises(RecordingError, match="order by a number or a string"):
        Condition("success", Op.GT, True)


async def test_time_window_robot_message_order_and_limit(recording: RecordingStore) -> None:
    await recording.write_recorded(
        [
            rec("e", at=2, robot="b"),
            rec("d", at=1, robot="a", message_id="m-d"),
            rec("c", at=1, robot="b"),
            rec("a", at=0, robot="a", mission_id="m1"),
            rec("b", at=3, robot="a", mission_id="m1"),
        ]
    )
    assert keys(await recording.find_recorded(RecordQuery("tf"))) == ["a", "c", "d", "e", "b"]
    window = RecordQuery("tf", since=T0 + timedelta(seconds=1), until=T0 + timedelta(seconds=3))
    assert keys(await recording.find_recorded(window)) == ["c", "d", "e"], "since inclusive, until exclusive"
    assert keys(await recording.find_recorded(RecordQuery("tf", robot_id="a"))) == ["a", "d", "b"]
    assert keys(await recording.find_recorded(RecordQuery("tf", message_id="m-d"))) == ["d"]
    assert keys(await recording.find_recorded(RecordQuery("tf", mission_id="m1"))) == ["a", "b"]
    newest = RecordQuery("tf", newest_first=True, limit=3)
    assert keys(await recording.find_recorded(newest)) == ["b", "e", "d"]


DOCS: dict[str, Any] = {
    "s1": {"name": "grab", "v": 1, "flag": True, "nested": {"deep": "abc"}, "arr": [5, 6]},
    "s2": {"name": "Grab", "v": 2.5, "flag": False, "nested": {"deep": "xbcx"}},
    "s3": {"name": "place", "v": "2", "flag": 1, "nested": {}},
    "s4": {"name": None, "v": -1, "nested": "flat"},
    "s5": {"v": 10},
    "s6": ["not", "an", "object"],
    "s7": 42,
    "s8": {"tags": ["red", "blue"], "items": [{"name": "a"}], "zones": {"1": "x"}, "ranges": [1, 9]},
}


@pytest.mark.parametrize(
    ("conditions", "expected"),
    [
        ([("name", Op.EQ, "grab")], ["s1"]),
        ([("name", Op.NE, "grab")], ["s2", "s3", "s4", "s5", "s6", "s7", "s8"]),
        ([("name", Op.EQ, None)], ["s4", "s5", "s6", "s7", "s8"]),
        ([("name", Op.NE, None)], ["s1", "s2", "s3"]),
        ([("v", Op.EQ, 1)], ["s1"]),
        ([("v", Op.EQ, 1.0)], ["s1"]),
        ([("v", Op.EQ, "2")], ["s3"]),
        ([("v", Op.GT, 1)], ["s2", "s5"]),
        ([("v", Op.GE, 1), ("v", Op.LT, 10)], ["s1", "s2"]),
        ([("v", Op.LE, "3")], ["s3"]),
        ([("flag", Op.EQ, True)], ["s1"]),
        ([("flag", Op.EQ, False)], ["s2"]),
        ([("flag", Op.EQ, 1)], ["s3"]),
        ([("flag", Op.NE, True)], ["s2", "s3", "s4", "s5", "s6", "s7", "s8"]),
        ([("nested.deep", Op.CONTAINS, "bc")], ["s1", "s2"]),
        ([("nested.deep", Op.CONTAINS, "a.c")], []),
        ([("nested", Op.EQ, "flat")], ["s4"]),
        ([("arr.1", Op.EQ, 6)], ["s1"]),
        # a path names one value: it goes through no array, and a digit is an array's index only
        ([("tags", Op.EQ, "red")], []),
        ([("tags", Op.NE, "red")], ["s1", "s2", "s3", "s4", "s5", "s6", "s7", "s8"]),
        ([("tags", Op.NE, None)], ["s8"]),
        ([("items.name", Op.EQ, "a")], []),
        ([("items.name", Op.EQ, None)], ["s1", "s2", "s3", "s4", "s5", "s6", "s7", "s8"]),
        ([("items.0.name", Op.EQ, "a")], ["s8"]),
        ([("zones.1", Op.EQ, "x")], []),
        ([("ranges", Op.GT, 5)], []),
        ([("ranges.1", Op.GT, 5)], ["s8"]),
        ([("1", Op.EQ, "an")], ["s6"]),
        ([("name", Op.EQ, "grab"), ("flag", Op.EQ, True), ("v", Op.LT, 2)], ["s1"]),
    ],
)
async def test_field_conditions_mean_the_same_on_every_adapter(
    recording: RecordingStore, conditions: list[tuple[str, Op, Any]], expected: list[str]
) -> None:
    await recording.write_recorded([rec(key, doc, at=i) for i, (key, doc) in enumerate(DOCS.items())])
    query = RecordQuery("tf", conditions=tuple(Condition(*c) for c in conditions))
    assert keys(await recording.find_recorded(query)) == expected


async def test_the_reference_queries(recording: RecordingStore) -> None:
    """Fig. 2: the latest failed attempt to grab a bottle; transforms between two frames in a window."""

    def behaviour(key: str, at: float, name: str, obj: str, success: bool) -> RecordedMessage:
        body = {"name": name, "object": obj, "success": success, "duration_s": 1.0}
        return rec(key, {"robot_id": "herb", "seq": int(at), "body": body}, type="behaviour", at=at)

    def tf(key: str, at: float, frame: str, child: str) -> RecordedMessage:
        return rec(key, {"frame": frame, "child_frame": child, "translation": {"x": at}}, at=at)

    await recording.write_recorded(
        [
            behaviour("g1", 1, "grab", "bottle", False),
            behaviour("g2", 2, "grab", "bottle", True),
            behaviour("g3", 3, "grab", "bottle", False),
            behaviour("g4", 4, "grab", "cup", False),
            behaviour("g5", 5, "place", "bottle", False),
            tf("t1", 1, "/kinect/depth", "/object/bottle"),
            tf("t2", 2, "/kinect/depth", "/object/bottle"),
            tf("t3", 3, "/kinect/depth", "/object/cup"),
            tf("t4", 4, "/rx28/tilt", "/object/bottle"),
            tf("t5", 5, "/kinect/depth", "/object/bottle"),
        ]
    )
    failed_grab = RecordQuery(
        "behaviour",
        conditions=(
            Condition("body.name", Op.EQ, "grab"),
            Condition("body.object", Op.EQ, "bottle"),
            Condition("body.success", Op.EQ, False),
        ),
        newest_first=True,
        limit=1,
    )
    assert keys(await recording.find_recorded(failed_grab)) == ["g3"]
    transforms = RecordQuery(
        "tf",
        conditions=(
            Condition("frame", Op.EQ, "/kinect/depth"),
            Condition("child_frame", Op.EQ, "/object/bottle"),
        ),
        since=T0 + timedelta(seconds=1),
        until=T0 + timedelta(seconds=5),
    )
    assert keys(await recording.find_recorded(transforms)) == ["t1", "t2"]


async def test_field_indexes_are_made_once_and_listed(recording: RecordingStore) -> None:
    await recording.write_recorded([rec("1")])
    await recording.ensure_field_index("tf", ["frame", "child_frame"])
    await recording.ensure_field_index("tf", ["frame", "child_frame"])
    await recording.ensure_field_index("brand_new", ["body.name"])
    assert await recording.field_indexes("tf") == [("frame", "child_frame")]
    assert await recording.field_indexes("brand_new") == [("body.name",)]


def outcome(
    key: str, at: float, name: Any, success: Any, duration: Any, robot: str = "herb"
) -> RecordedMessage:
    body = {"name": name, "success": success, "duration_s": duration}
    return rec(key, {"body": body}, type="behaviour", at=at, robot=robot)


async def test_performance_evaluation_is_computed_alike(recording: RecordingStore) -> None:
    grabs = [(True, 12.5), (False, 30.25), (True, 11.0), (True, 14.125), (False, 2)]
    places = [(True, 3.3), (True, 4.4)]
    await recording.write_recorded(
        [outcome(f"g{i}", i, "grab", ok, d) for i, (ok, d) in enumerate(grabs)]
        + [outcome(f"p{i}", i, "place", ok, d, robot="other") for i, (ok, d) in enumerate(places)]
        + [
            outcome("x1", 1, "grab", True, None),  # no duration: not counted
            outcome("x2", 1, "grab", True, "12"),  # a duration that is not a number: not counted
            outcome("x3", 1, None, True, 1.0),  # no name: not counted
            outcome("x4", 1, "grab", "yes", 20.0),  # success is not true: a failure
            outcome("late", 100, "grab", True, 1000.0),
        ]
    )
    until = T0 + timedelta(seconds=50)
    stats = await recording.outcome_stats("behaviour", OutcomeFields(), until=until)
    durations = [d for _, d in grabs] + [20.0]
    grab, place = stats
    assert (grab.name, grab.successes, grab.failures, grab.runs) == ("grab", 3, 3, 6)
    assert grab.mean_duration == pytest.approx(statistics.fmean(durations), abs=1e-9)
    assert grab.std_duration == pytest.approx(statistics.pstdev(durations), abs=1e-9)
    assert grab.success_rate == 0.5
    assert (place.name, place.successes, place.failures) == ("place", 2, 0)
    assert place.std_duration == pytest.approx(0.55, abs=1e-9)
    only_other = await recording.outcome_stats("behaviour", OutcomeFields(), robot_id="other")
    assert [s.name for s in only_other] == ["place"]
    assert await recording.outcome_stats("nothing_here", OutcomeFields()) == []


async def test_evaluation_results_are_identical_across_adapters(recording: RecordingStore) -> None:
    """The figures a fixed data set gives, to the last kept digit, whichever database computes them."""
    durations = [0.1 * i + 1 / 3 for i in range(1, 60)]
    await recording.write_recorded(
        [outcome(f"k{i}", i, f"b{i % 3}", i % 4 != 0, d) for i, d in enumerate(durations)]
    )
    stats = await recording.outcome_stats("behaviour", OutcomeFields())
    assert [(s.name, s.successes, s.failures, s.mean_duration, s.std_duration) for s in stats] == [
        ("b0", 15, 5, 3.283333333, 1.729884389),
        ("b1", 15, 5, 3.383333333, 1.729884389),
        ("b2", 14, 5, 3.333333333, 1.643167673),
    ]


async def test_retention_primitives(recording: RecordingStore) -> None:
    await recording.write_recorded([rec(f"k{i}", at=i, size=10 * i) for i in range(6)])
    assert await recording.oldest_recorded("tf", 3) == [("k0", 0), ("k1", 10), ("k2", 20)]
    assert await recording.delete_recorded_before("tf", T0 + timedelta(seconds=2)) == 2
    assert await recording.delete_recorded("tf", ["k2", "k4", "missing"]) == 2
    assert keys(await recording.find_recorded(RecordQuery("tf"))) == ["k3", "k5"]
    assert await recording.delete_recorded_before("never_seen", T0) == 0
    assert await recording.oldest_recorded("never_seen", 3) == []


async def test_the_sweep_holds_the_size_samples_to_their_bound(recording: RecordingStore) -> None:
    samples = [StorageSample(T0 + timedelta(minutes=i), "run-a", 1000 + i, i) for i in range(10)]
    for sample in samples:
        await recording.add_sample(sample)
    now = T0 + timedelta(minutes=9, seconds=30)
    by_age = RetentionSweeper(recording, {}, samples_retention("5m"))
    assert await by_age.sweep(now) == {SAMPLES: 5}  # sampled before 04:30
    assert await recording.samples() == samples[5:]
    by_number = RetentionSweeper(recording, {}, samples_retention("2"))
    assert await by_number.sweep(now) == {SAMPLES: 3}
    assert await recording.samples() == samples[8:]
    assert await by_number.sweep(now) == {}


def test_the_size_samples_are_bounded_by_an_age_or_a_number_not_a_size() -> None:
    with pytest.raises(ValueError, match="FLEETBUS_RECORDER_SAMPLES_KEEP: bounded by an age"):
        samples_retention("1GB")


async def test_storage_samples_and_size(recording: RecordingStore) -> None:
    before = await recording.database_bytes()
    await recording.write_recorded([rec(f"k{i}", {"pad": "x" * 2000}) for i in range(50)])
    after = await recording.database_bytes()
    assert after > before and after >= 50 * 2000
    samples = [
        StorageSample(T0, "run-a", 1000, 0),
        StorageSample(T0 + timedelta(seconds=60), "run-a", 2000, 120),
        StorageSample(T0 + timedelta(seconds=61), "run-b", 2100, 0),
    ]
    for sample in samples:
        await recording.add_sample(sample)
    await recording.add_sample(samples[1])
    assert await recording.samples() == samples
    assert await recording.samples(since=T0 + timedelta(seconds=30)) == samples[1:]
