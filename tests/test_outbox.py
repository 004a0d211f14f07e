"""The robot's outbox on disk (TinyDB segments): order, policies, crash leftovers. No broker needed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from publishers.outbox import Outbox, OutboxFull, Overflow, TypePolicy
from publishers.sequence import SequenceCounter, legacy_floor
from publishers.storage import AtomicJSONStorage
from schemas.envelope import Event, build_event, parse_event
from tests.factories import hazard, status


def events(kind: str, first: int, count: int) -> list[Event]:
    body = hazard if kind == "hazard" else status
    return [build_event(kind, "explorer1", first + i, body()) for i in range(count)]


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
    assert reopened.max_seq() == 34


def test_settle_removes_confirmed_moves_refused_and_keeps_the_rest(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, segment_events=4)
    outbox.append(events("hazard", 0, 10))
    window = outbox.take(6)
    assert [entry.seq for entry in window] == [0, 1, 2, 3, 4, 5]
    outbox.settle(window[:5], {window[2].message_id: "unroutable (312 NO_ROUTE)"})
    assert seqs(outbox) == [5, 6, 7, 8, 9], "the unsettled one stays first"
    [refused] = outbox.refused()
    assert (refused.seq, refused.reason) == (2, "unroutable (312 NO_ROUTE)")
    assert len(list(tmp_path.glob("seg-*.json"))) == 2, "the emptied segment file is gone"
    outbox.settle(outbox.take(100))
    assert outbox.pending() == 0 and not list(tmp_path.glob("seg-*.json"))


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
    big = build_event("hazard", "explorer1", 0, {**hazard(), "description": "x" * 500})
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
    big = build_event("hazard", "explorer1", 0, {**hazard(), "description": "x" * 500})
    outbox.append([big, *events("hazard", 1, 1)])
    blobs = list(tmp_path.glob("blob-*.json"))
    assert len(blobs) == 1
    assert parse_event(outbox.entries()[0].body) == big
    outbox.settle(outbox.take(1))
    assert not blobs[0].exists()


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


def test_the_next_sequence_number_survives_reopening_however_the_outbox_emptied(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path, {"status": TypePolicy(Overflow.DROP_OLDEST, 2)})
    assert outbox.next_seq() == 0
    outbox.append(events("hazard", 0, 3))
    assert outbox.next_seq() == 3, "the newest waiting event"
    outbox.settle(outbox.take(3))
    outbox.close()
    reopened = Outbox(tmp_path, {"status": TypePolicy(Overflow.DROP_OLDEST, 2)})
    assert reopened.pending() == 0 and reopened.next_seq() == 3, "recorded before they left"
    reopened.append(events("status", 7, 3))  # 7 dropped at once
    window = reopened.take(2)
    reopened.settle(window, {window[1].message_id: "unroutable"})
    reopened.close()
    assert Outbox(tmp_path).next_seq() == 10


def test_a_client_numbers_on_from_its_outbox_and_from_the_old_state_file(tmp_path: Path) -> None:
    (tmp_path / "state.json").write_text('{"sequence": {"1": {"next": 42}}}')
    assert legacy_floor(tmp_path / "state.json") == 42
    assert legacy_floor(tmp_path / "missing.json") == 0
    counter = SequenceCounter(5)
    assert counter.reserve(3) == 5
    counter.at_least(2)
    assert counter.reserve() == 8
