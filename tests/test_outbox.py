"""The robot's outbox on disk (TinyDB segments): order, policies, crash leftovers. No broker needed."""

from __future__ import annotations

import json
import logging
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from fleetbus.publishers import outbox as outbox_module
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.errors import ClientClosed, PublisherError
from fleetbus.publishers.outbox import (
    Outbox,
    OutboxError,
    OutboxFull,
    Overflow,
    TypePolicy,
    policies_with_limits,
)
from fleetbus.publishers.sequence import SequenceCounter
from fleetbus.publishers.state_lock import RobotStateInUse
from fleetbus.publishers.storage import AtomicJSONStorage
from fleetbus.schemas.envelope import Event, build_event, new_epoch, parse_event
from tests.factories import hazard, status

EPOCH = new_epoch()


def events(kind: str, first: int, count: int, epoch: str = EPOCH) -> list[Event]:
    body = hazard if kind == "hazard" else status
    return [build_event(kind, "explorer1", epoch, first + i, body()) for i in range(count)]


def seqs(outbox: Outbox) -> list[int]:
    return [entry.seq for entry in outbox.entries()]


def test_entries_wait_in_order_across_segments_and_survive_reopening(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, segment_events=10)
    sent = events("hazard", 0, 25) + events("status", 25, 10)
    outbox.append(sent[:7])
    outbox.append(sent[7:])
    assert len(list(tmp_path.glob("seg-*.json"))) == 4
    outbox.close()

    reopened = Outbox(tmp_path, segment_events=10)
    assert seqs(reopened) == list(range(35))
    assert [parse_event(entry.body) for entry in reopened.entries()] == sent, "bodies byte for byte"
    assert reopened.counts() == {"hazard": 25, "status": 10}
    assert {entry.epoch for entry in reopened.entries()} == {EPOCH}


def test_settle_removes_confirmed_moves_refused_and_keeps_the_rest(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, segment_events=4)
    outbox.append(events("hazard", 0, 10))
    window = outbox.take(6)
    assert [entry.seq for entry in window] == [0, 1, 2, 3, 4, 5]
    outbox.settle(window[:5], {window[2].message_id: "unroutable (312 NO_ROUTE)"})
    assert seqs(outbox) == [5, 6, 7, 8, 9], "the unsettled one stays first"
    [refused] = outbox.refused()
    assert (refused.epoch, refused.seq, refused.reason) == (EPOCH, 2, "unroutable (312 NO_ROUTE)")
    assert len(list(tmp_path.glob("seg-*.json"))) == 2, "the emptied segment file is gone"
    outbox.settle(outbox.take(100))
    assert outbox.pending() == 0 and not list(tmp_path.glob("seg-*.json"))


def test_the_refused_list_keeps_the_newest_reasons_and_counts_them_all(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A broker that refuses everything a robot sends (a misconfigured exchange, say) must not
    grow the list, rewritten whole at each refusal, for ever: it keeps the newest reasons, and the
    counts by type stay whole."""
    monkeypatch.setattr(outbox_module, "REFUSED_KEPT", 3)
    outbox = Outbox(tmp_path, segment_events=4)
    outbox.append(events("hazard", 0, 5) + events("status", 5, 2))
    for window in (outbox.take(4), outbox.take(3)):
        outbox.settle(window, {entry.message_id: f"refused {entry.seq}" for entry in window})
    assert [entry.seq for entry in outbox.refused()] == [4, 5, 6], "the newest"
    summary = outbox.summary()
    assert (summary["hazard"].refused, summary["status"].refused) == (5, 2)
    outbox.close()
    assert Outbox(tmp_path).summary()["hazard"].refused == 5, "kept on disk"


def test_windows_in_flight_are_taken_once_and_a_nacked_entry_is_taken_again(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, segment_events=4)
    outbox.append(events("hazard", 0, 10))
    first, second = outbox.take(4), outbox.take(4)
    assert [e.seq for e in first] == [0, 1, 2, 3] and [e.seq for e in second] == [4, 5, 6, 7]
    outbox.settle([e for e in first if e.seq != 1], window=first)  # the broker nacked seq 1
    assert [e.seq for e in outbox.take(4)] == [1, 8, 9], "seq 1 again; the second window still away"
    outbox.settle(second, window=second)
    assert seqs(outbox) == [1, 8, 9]
    outbox.release()
    assert [e.seq for e in outbox.take(10)] == [1, 8, 9], "after a broken connection, all again"


def test_whole_segment_takes_are_deleted_on_settle_without_being_read_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    outbox = Outbox(tmp_path, segment_events=4, blob_bytes=600)
    big = build_event("hazard", "explorer1", EPOCH, 0, {**hazard(), "description": "x" * 500})
    outbox.append([big, *events("hazard", 1, 11)])
    first = outbox.take(6, whole_segments=True)
    assert [e.seq for e in first] == [0, 1, 2, 3], "stops before a segment it could take only part of"
    second = outbox.take(6, whole_segments=True)
    assert [e.seq for e in second] == [4, 5, 6, 7]
    monkeypatch.setattr(outbox, "_docs", lambda segment: pytest.fail("a wholly settled segment was read"))
    outbox.settle(second, window=second)
    outbox.settle(first, window=first)
    monkeypatch.undo()
    assert seqs(outbox) == [8, 9, 10, 11]
    assert len(list(tmp_path.glob("seg-*.json"))) == 1 and not list(tmp_path.glob("blob-*.json"))
    assert [e.seq for e in outbox.take(2, whole_segments=True)] == [8, 9], "a first segment, in part"


def test_telemetry_drops_its_oldest_and_counts_them(tmp_path: Path) -> None:
    policies = {
        "status": TypePolicy(Overflow.DROP_OLDEST, 5),
        "hazard": TypePolicy(Overflow.KEEP, 100),
    }
    outbox = Outbox(tmp_path, policies, segment_events=3)
    outbox.append(events("status", 0, 4) + events("hazard", 4, 2))
    outbox.append(events("status", 6, 4))
    assert outbox.counts() == {"status": 5, "hazard": 2}
    assert seqs(outbox) == [3, 4, 5, 6, 7, 8, 9], "the three oldest status events went"
    assert outbox.dropped() == {"status": 3}
    outbox.close()
    assert Outbox(tmp_path, policies).dropped() == {"status": 3}, "the count is on disk"


def test_drop_spares_the_window_in_flight(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, {"status": TypePolicy(Overflow.DROP_OLDEST, 3)})
    outbox.append(events("status", 0, 3))
    in_flight = outbox.take(2)
    outbox.append(events("status", 3, 1))
    assert seqs(outbox) == [0, 1, 3], "seq 2 dropped, not the two being sent"
    outbox.settle(in_flight)
    assert seqs(outbox) == [3]


def test_a_type_never_dropped_refuses_past_its_limit_and_takes_nothing(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, {"hazard": TypePolicy(Overflow.KEEP, 3)})
    outbox.append(events("hazard", 0, 2))
    with pytest.raises(OutboxFull, match="2 hazard events wait already and hazard is never dropped"):
        outbox.append(events("hazard", 2, 2) + events("status", 4, 1))
    assert seqs(outbox) == [0, 1]


def test_large_bodies_wait_in_files_of_their_own(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, blob_bytes=600)
    big = build_event("hazard", "explorer1", EPOCH, 0, {**hazard(), "description": "x" * 500})
    outbox.append([big, *events("hazard", 1, 1)])
    blobs = list(tmp_path.glob("blob-*.json"))
    assert len(blobs) == 1
    assert parse_event(outbox.entries()[0].body) == big
    outbox.settle(outbox.take(1))
    assert not blobs[0].exists()


def test_a_missing_body_file_is_an_outbox_error_and_the_take_takes_nothing(tmp_path: Path) -> None:
    """The sender tells the outbox's own failures from the network's (both raise OSErrors)."""
    outbox = Outbox(tmp_path, blob_bytes=600)
    big = build_event("hazard", "explorer1", EPOCH, 1, {**hazard(), "description": "x" * 500})
    outbox.append([*events("hazard", 0, 1), big, *events("hazard", 2, 1)])
    [blob] = tmp_path.glob("blob-*.json")
    kept = blob.read_bytes()
    blob.unlink()
    with pytest.raises(OutboxError, match=r"could not read the events to send: FileNotFoundError"):
        outbox.take(10)
    blob.write_bytes(kept)
    assert [entry.seq for entry in outbox.take(10)] == [0, 1, 2], "nothing was left in flight"


def test_a_settle_that_failed_on_a_file_finishes_when_tried_again(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path)
    outbox.append(events("hazard", 0, 3))
    window = outbox.take(3)
    refused = {window[1].message_id: "unroutable (312 NO_ROUTE)"}
    real = outbox._delete_segment

    def no_space(*args: object) -> None:
        raise OSError(28, "No space left on device")

    outbox._delete_segment = no_space  # type: ignore[method-assign]
    with pytest.raises(OutboxError, match=r"could not settle .*No space left"):
        outbox.settle(window, refused, window)
    outbox._delete_segment = real  # type: ignore[method-assign]
    outbox.settle(window, refused, window)
    assert outbox.pending() == 0
    assert len(outbox.refused()) == 1 and outbox.refused_counts() == {"hazard": 1}, "counted once"
    outbox.close()
    (tmp_path / "refused.json").write_text("{not json")  # found when the outbox opens: set aside
    outbox = Outbox(tmp_path)
    outbox.append(events("hazard", 3, 1))
    window = outbox.take(1)
    outbox.settle(window, {window[0].message_id: "refused"}, window)
    assert outbox.refused_counts() == {"hazard": 2}, "the counts in meta.json are kept"
    assert len(outbox.refused()) == 1


def test_leftovers_of_a_write_cut_short_are_cleaned(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, blob_bytes=1000)
    outbox.append(events("hazard", 0, 2))
    outbox.close()
    (tmp_path / ".seg-000000000000.json.tmp").write_text('{"events": {"1": ')  # a torn temporary file
    (tmp_path / "blob-orphan.json").write_text("{}")  # written just before a crash, never appended
    reopened = Outbox(tmp_path)
    assert seqs(reopened) == [0, 1]
    assert not (tmp_path / ".seg-000000000000.json.tmp").exists()
    assert not (tmp_path / "blob-orphan.json").exists()


def test_the_storage_replaces_its_file_whole(tmp_path: Path) -> None:
    storage = AtomicJSONStorage(tmp_path / "db.json")
    storage.write({"t": {"1": {"a": 1}}})
    storage.write({"t": {"1": {"a": 2}}})
    assert json.loads((tmp_path / "db.json").read_text()) == {"t": {"1": {"a": 2}}}
    assert [path.name for path in tmp_path.iterdir()] == ["db.json"], "no temporary file left"


def test_waiting_events_keep_the_epoch_and_number_they_were_built_with(tmp_path: Path) -> None:
    """A later run numbers in an epoch of its own; what an earlier run left goes out as it was
    built, so a resend of it is an exact duplicate."""
    earlier, later = new_epoch(), new_epoch()
    outbox = Outbox(tmp_path)
    left = events("hazard", 0, 3, earlier)
    outbox.append(left)
    outbox.close()
    reopened = Outbox(tmp_path)
    reopened.append(events("hazard", 0, 2, later))
    assert [(e.epoch, e.seq) for e in reopened.entries()] == [
        (earlier, 0),
        (earlier, 1),
        (earlier, 2),
        (later, 0),
        (later, 1),
    ]
    assert [parse_event(e.body) for e in reopened.entries()[:3]] == left, "byte for byte, message ids too"


def test_epochs_sort_in_the_order_they_began_and_numbers_count_from_0() -> None:
    start = datetime(2026, 11, 24, 20, 56, 1, 123456, tzinfo=timezone.utc)
    minted = [new_epoch(start + timedelta(milliseconds=i)) for i in (0, 1, 999, 1000)]
    assert minted == sorted(minted) and minted[0].startswith("20261124T205601123Z-")
    assert len({new_epoch(start) for _ in range(100)}) == 100, "one millisecond, distinct epochs"
    counter = SequenceCounter()
    assert counter.reserve(3) == 0
    assert counter.reserve() == 3


def test_hazards_and_localisations_are_taken_before_the_telemetry_waiting_longer(tmp_path: Path) -> None:
    """After an outage: the express lane's types first, each kind in its own order, then the rest
    in theirs; settling the windows removes each once."""
    outbox = Outbox(tmp_path, segment_events=10)
    located = [build_event("localisation", "explorer1", EPOCH, 30, {"localised": True})]
    outbox.append(events("status", 0, 25) + events("hazard", 25, 2) + events("status", 27, 3) + located)
    outbox.append(events("hazard", 31, 1) + events("status", 32, 5))
    first = outbox.take(4, whole_segments=True)
    assert [(e.type, e.seq) for e in first] == [
        ("hazard", 25),
        ("hazard", 26),
        ("localisation", 30),
        ("hazard", 31),
    ]
    second = outbox.take(12, whole_segments=True)
    assert [e.seq for e in second] == list(range(10)), "then the oldest, whole segments"
    outbox.settle(first + second)
    rest = outbox.take(100)
    assert [e.seq for e in rest] == [*range(10, 25), 27, 28, 29, *range(32, 37)]
    outbox.settle(rest)
    assert outbox.pending() == 0


def test_a_hazard_never_overtakes_an_older_one_when_the_telemetry_before_it_is_in_flight(
    tmp_path: Path,
) -> None:
    """The window in flight ends just before a hazard: the next take sends that hazard before the
    one behind the next telemetry, as the express lane must receive them (seen with a broker kill)."""
    outbox = Outbox(tmp_path, segment_events=100)
    outbox.append(events("status", 0, 3))
    assert [e.seq for e in outbox.take(3, whole_segments=True)] == [0, 1, 2]
    outbox.append(events("hazard", 3, 1) + events("status", 4, 3) + events("hazard", 7, 1))
    assert [(e.type, e.seq) for e in outbox.take(3, whole_segments=True)] == [
        ("hazard", 3),
        ("hazard", 7),
        ("status", 4),
    ]


def test_limits_from_a_setting_keep_each_types_overflow(tmp_path: Path) -> None:
    policies = policies_with_limits("status=3, hazard=2")
    assert policies["status"] == TypePolicy(Overflow.DROP_OLDEST, 3)
    assert policies["hazard"] == TypePolicy(Overflow.KEEP, 2)
    outbox = Outbox(tmp_path, policies)
    outbox.append(events("status", 0, 5))
    assert seqs(outbox) == [2, 3, 4] and outbox.dropped() == {"status": 2}
    assert Outbox(tmp_path, policies, read_only=True).dropped() == {"status": 2}, "kept on disk"
    with pytest.raises(OutboxFull):
        outbox.append(events("hazard", 5, 3))
    for text, error in (("stats=3", "unknown type 'stats'"), ("status=0", "a whole number, 1 or more")):
        with pytest.raises(ValueError, match=error):
            policies_with_limits(text)


def test_a_closed_client_takes_no_more_events(tmp_path: Path) -> None:
    """After close() the outbox's files and the robot's lock are let go (another client may own
    them): publishing, enqueueing and flushing raise ClientClosed, and nothing is stored."""
    url = "amqp://explorer1:secret@127.0.0.1:1/"  # no broker needed: nothing is to be sent
    robot = RobotClient(url, state_dir=tmp_path, connect_timeout=0.5, durable=False)
    built = robot.build([("status", status())])
    robot.close()
    with pytest.raises(ClientClosed, match="closed"):
        robot.publish("status", status(), wait=False)
    with pytest.raises(ClientClosed):
        robot.publish_many([("status", status())], wait=False)
    with pytest.raises(ClientClosed):
        robot.enqueue(built, wait=False)
    with pytest.raises(ClientClosed):
        robot.flush(timeout=0.1)
    with pytest.raises(ClientClosed):
        robot.start()  # a sender started now would work on files the client no longer holds
    assert not robot._sender._thread.is_alive()
    assert Outbox(tmp_path / "explorer1" / "outbox", read_only=True).pending() == 0


def test_the_clients_own_errors_are_publisher_errors_and_keep_their_old_bases() -> None:
    """Robot code catches PublisherError for whatever the client raises of its own."""
    for error in (OutboxFull, OutboxError, RobotStateInUse, ClientClosed):
        assert issubclass(error, PublisherError), error
    assert issubclass(RobotStateInUse, RuntimeError)


def test_a_truncated_segment_is_set_aside_counted_and_the_outbox_opens(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = Outbox(tmp_path, segment_events=10, durable=False)
    outbox.append(events("hazard", 0, 20))
    outbox.close()
    first = tmp_path / "seg-000000000000.json"
    first.write_bytes(first.read_bytes()[:300])  # a disk that failed in the middle of it

    with caplog.at_level(logging.ERROR, logger="fleetbus.robot.outbox"):
        reopened = Outbox(tmp_path, segment_events=10, durable=False)
    assert seqs(reopened) == list(range(10, 20)), "the readable segment still waits"
    assert not first.exists()
    [aside] = tmp_path.glob("seg-000000000000.json.unreadable-*")
    assert aside.stat().st_size == 300, "kept as it was"
    assert reopened.dropped() == {"unreadable-file": 1}
    assert str(first) in caplog.text and aside.name in caplog.text and "events" in caplog.text
    reopened.close()
    assert Outbox(tmp_path, segment_events=10).dropped() == {"unreadable-file": 1}, "counted once, on disk"


def test_a_corrupt_meta_file_is_set_aside_and_the_counts_start_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = Outbox(tmp_path, {"status": TypePolicy(Overflow.DROP_OLDEST, 2)}, durable=False)
    outbox.append(events("status", 0, 5))
    assert outbox.dropped() == {"status": 3}
    outbox.close()
    (tmp_path / "meta.json").write_text('{"counters": {"1": {"dropped": {"status": "three"}}}}')

    with caplog.at_level(logging.ERROR, logger="fleetbus.robot.outbox"):
        reopened = Outbox(tmp_path, durable=False)
    assert reopened.dropped() == {"unreadable-file": 1}
    assert seqs(reopened) == [3, 4]
    assert len(list(tmp_path.glob("meta.json.unreadable-*"))) == 1
    assert "meta.json" in caplog.text and "counts" in caplog.text


def test_a_robot_whose_outbox_has_a_corrupt_file_starts_and_says_so_in_its_status(tmp_path: Path) -> None:
    url = "amqp://explorer1:secret@127.0.0.1:1/"  # no broker needed: nothing is sent
    folder = tmp_path / "explorer1" / "outbox"
    Outbox(folder, durable=False).append(events("hazard", 0, 3))
    (folder / "seg-000000000000.json").write_text('{"events": {"1": {"epoch": ')
    (folder / "meta.json").write_text("not json")

    robot = RobotClient(url, state_dir=tmp_path, durable=False)
    try:
        [event] = robot.build([("status", status())])
        assert event.body.outbox_dropped == {"unreadable-file": 2}
    finally:
        robot.close()
