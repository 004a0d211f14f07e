"""A window of the recording is streamed in pages (what `fleetbus replay` sends), on every adapter:
never more than a page per type is read at once, and the merged order is the recording order."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from typing import Any

from fleetbus.workers.recorder.queries import recorded_between
from fleetbus.workers.store.recordings import RecordedMessage, RecordingStore, RecordQuery

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)


class PageWatch:
    """The recording, with the size of every read it answers."""

    def __init__(self, store: RecordingStore) -> None:
        self._store = store
        self.reads: list[int] = []

    async def find_recorded(self, query: RecordQuery) -> list[RecordedMessage]:
        found = await self._store.find_recorded(query)
        self.reads.append(len(found))
        return found

    def __getattr__(self, name: str) -> Any:
        return getattr(self._store, name)


def message(type: str, key: str, at: datetime) -> RecordedMessage:
    return RecordedMessage(key, type, at, "r1.events", f"r1.{type}", "r1", "r1", document={"k": key})


async def test_a_window_is_read_a_page_per_type_at_a_time_in_recording_order(
    recording: RecordingStore,
) -> None:
    # several records at the same moment: the pages go on after (time, key), not after the time
    statuses = [message("status", f"s{i:02d}", T0 + timedelta(seconds=i // 3)) for i in range(23)]
    tfs = [message("tf", f"t{i:02d}", T0 + timedelta(seconds=i, milliseconds=500)) for i in range(9)]
    await recording.write_recorded([*statuses, *tfs])
    await recording.write_recorded([message("status", "late", T0 + timedelta(hours=1))])
    watch = PageWatch(recording)
    streamed = [
        record.key
        async for record in recorded_between(watch, T0, T0 + timedelta(minutes=1), page=4)  # type: ignore[arg-type]
    ]
    expected = sorted([*statuses, *tfs], key=lambda r: (r.recorded_at, r.key))
    assert streamed == [r.key for r in expected], "every record of the window once, in recording order"
    assert max(watch.reads) == 4, "no read larger than a page"
    assert len(watch.reads) == -(-23 // 4) + -(-9 // 4) + (23 % 4 == 0) + (9 % 4 == 0)
