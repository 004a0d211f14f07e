"""Which recorded messages an export takes: robots, types, ROS topics and a window in nanoseconds.

The store's window is on ``recorded_at`` (microseconds); a ROS message's own log time is in
nanoseconds (``log_time_ns``). The store is asked for the window widened to whole microseconds,
and :meth:`Selection.keeps` cuts it to the nanosecond.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.ros import ROS_TYPE
from fleetbus.workers.store.recordings import RecordedMessage, RecordingError


def nanos_of(moment: datetime) -> int:
    return round(moment.timestamp() * 1_000_000) * 1000


def log_time_ns(record: RecordedMessage) -> int:
    """When a record was recorded, in ns: a ROS message's own log time, else ``recorded_at``."""
    document: Any = record.document
    own = document.get("log_time_ns") if record.type == ROS_TYPE and isinstance(document, dict) else None
    if isinstance(own, int):
        return own
    return nanos_of(record.recorded_at)


@dataclass(frozen=True)
class Selection:
    robots: tuple[str, ...] = ()
    types: tuple[str, ...] = ()
    topics: tuple[str, ...] = ()
    """ROS topic patterns (``/scan``, ``/camera/*``): only ROS messages on them."""
    since_ns: int | None = None
    """Inclusive."""
    until_ns: int | None = None
    """Exclusive."""

    def __post_init__(self) -> None:
        if self.since_ns is not None and self.until_ns is not None and self.since_ns >= self.until_ns:
            raise RecordingError(
                f"the window is empty or inverted: --since ({self.since_ns} ns) is not before --until "
                f"({self.until_ns} ns)"
            )

    @property
    def chosen_types(self) -> list[str]:
        return list(self.types) or ([ROS_TYPE] if self.topics else [])

    def store_window(self) -> tuple[datetime | None, datetime | None]:
        """The window for the store, widened to whole microseconds."""
        since = _moment(self.since_ns // 1000) if self.since_ns is not None else None
        until = _moment(-(-self.until_ns // 1000)) if self.until_ns is not None else None
        return since, until

    def keeps(self, record: RecordedMessage) -> bool:
        if self.robots and record.robot_id not in self.robots:
            return False
        if self.topics:
            document = record.document if isinstance(record.document, dict) else {}
            topic = str(document.get("topic", ""))
            if record.type != ROS_TYPE or not any(fnmatch.fnmatchcase(topic, p) for p in self.topics):
                return False
        at = log_time_ns(record)
        if self.since_ns is not None and at < self.since_ns:
            return False
        return self.until_ns is None or at < self.until_ns

    def metadata(self) -> dict[str, str]:
        """What the file says it holds (an MCAP metadata record)."""
        return {
            "robots": ",".join(self.robots) or "all",
            "types": ",".join(self.chosen_types) or "all but copies",
            "topics": ",".join(self.topics) or "all",
            "since_ns": "" if self.since_ns is None else str(self.since_ns),
            "until_ns": "" if self.until_ns is None else str(self.until_ns),
            "since": "" if self.since_ns is None else _moment(self.since_ns // 1000).isoformat(),
            "until": "" if self.until_ns is None else _moment(self.until_ns // 1000).isoformat(),
        }


def _moment(micros: int) -> datetime:
    seconds, rest = divmod(micros, 1_000_000)
    return datetime.fromtimestamp(seconds, timezone.utc).replace(microsecond=rest)
