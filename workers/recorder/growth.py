"""How fast the recording grows: MB and inserts per minute, from the recorder's size samples.

The recorder looks at the database every ``sample_interval`` seconds and notes its size and how
many records it inserted since its previous look; the looks are gathered into buckets (a
minute, ten minutes…) for reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.recordings import StorageSample

EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
#: The shortest and longest bucket (the recorder looks once a minute by default; a bucket shorter
#: than the clock's microsecond would be none at all).
SHORTEST_BUCKET = timedelta(seconds=1)
LONGEST_BUCKET = timedelta(days=1)


@dataclass(frozen=True)
class Growth:
    start: datetime
    end: datetime
    database_bytes: int
    """The database's size at ``end``."""
    grown_bytes: int
    inserted: int

    @property
    def seconds(self) -> float:
        return (self.end - self.start).total_seconds()

    @property
    def megabytes_per_minute(self) -> float:
        return self.grown_bytes / 1e6 / self.seconds * 60 if self.seconds > 0 else 0.0

    @property
    def inserts_per_minute(self) -> float:
        return self.inserted / self.seconds * 60 if self.seconds > 0 else 0.0


def growth(samples: Sequence[StorageSample], every: timedelta) -> list[Growth]:
    """One row per bucket of ``every`` (aligned on the epoch) that has samples.

    Growth is the size at the bucket's last sample less the size at the sample before the bucket
    (any recorder's: a standby recorder looks at the same database), and inserts are what the
    bucket's samples counted (a standby counts none), so two recorders never count anything twice.
    A bucket outside :data:`SHORTEST_BUCKET` to :data:`LONGEST_BUCKET` is a :class:`ValueError`.
    """
    if not SHORTEST_BUCKET <= every <= LONGEST_BUCKET:
        raise ValueError(f"a bucket must be from {SHORTEST_BUCKET} to {LONGEST_BUCKET}, not {every}")
    ordered = sorted(samples, key=lambda s: (s.sampled_at, s.run_id))
    buckets: dict[int, list[StorageSample]] = {}
    for sample in ordered:
        buckets.setdefault(int((sample.sampled_at - EPOCH) / every), []).append(sample)
    rows = []
    previous: StorageSample | None = None
    for _, inside in sorted(buckets.items()):
        first = previous or inside[0]
        last = inside[-1]
        inserted = sum(s.inserted for s in inside if s is not first)
        if last.sampled_at > first.sampled_at:
            rows.append(
                Growth(
                    first.sampled_at,
                    last.sampled_at,
                    last.database_bytes,
                    last.database_bytes - first.database_bytes,
                    inserted,
                )
            )
        previous = last
    return rows
