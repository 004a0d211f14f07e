"""Bounded recording: per type, keep records for a time, or up to a size or a number of them
(the policies as :mod:`fleetbus.limits` reads them from specs like ``status=7d`` or ``*=1GB``)."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime, timezone
from typing import TYPE_CHECKING

from fleetbus.bounds import register_retention
from fleetbus.limits import Retention, policy_for

if TYPE_CHECKING:
    from fleetbus.workers.store.recordings import RecordingStore

SWEEP_CHUNK = 1000
#: What the sweep calls the recorders' size samples in what it deleted (not a recorded type).
SAMPLES = "size samples"


def samples_retention(text: str) -> Retention:
    """``FLEETBUS_RECORDER_SAMPLES_KEEP``: an age or a number of samples; ValueError naming it."""
    return register_retention(text, "FLEETBUS_RECORDER_SAMPLES_KEEP")


class RetentionSweeper:
    """Deletes what the policies no longer keep; run it every so often while recording."""

    def __init__(
        self, store: RecordingStore, policies: Mapping[str, Retention], samples: Retention | None = None
    ) -> None:
        self._store = store
        self._policies = dict(policies)
        self._samples = samples

    async def sweep(self, now: datetime | None = None) -> dict[str, int]:
        """Records deleted, by type."""
        now = now or datetime.now(timezone.utc)
        deleted: dict[str, int] = {}
        for type in await self._store.recorded_types():
            policy = policy_for(self._policies, type)
            if policy is not None:
                count = await self._apply(type, policy, now)
                if count:
                    deleted[type] = count
        if self._samples is not None:
            count = await self._prune_samples(self._samples, now)
            if count:
                deleted[SAMPLES] = count
        return deleted

    async def _prune_samples(self, policy: Retention, now: datetime) -> int:
        before = now - policy.max_age if policy.max_age is not None else None
        deleted = 0
        while True:
            count = await self._store.prune_samples(before, policy.max_records, SWEEP_CHUNK)
            deleted += count
            if count < SWEEP_CHUNK:
                return deleted

    async def _apply(self, type: str, policy: Retention, now: datetime) -> int:
        deleted = 0
        if policy.max_age is not None:
            deleted += await self._store.delete_recorded_before(type, now - policy.max_age)
        if policy.max_records is None and policy.max_bytes is None:
            return deleted
        summary = await self._store.type_summary(type)
        records, size = summary.records, summary.bytes
        while (policy.max_records is not None and records > policy.max_records) or (
            policy.max_bytes is not None and size > policy.max_bytes
        ):
            doomed: list[str] = []
            for key, record_size in await self._store.oldest_recorded(type, SWEEP_CHUNK):
                over_count = policy.max_records is not None and records > policy.max_records
                over_size = policy.max_bytes is not None and size > policy.max_bytes
                if not (over_count or over_size):
                    break
                doomed.append(key)
                records -= 1
                size -= record_size
            if not doomed:
                break
            deleted += await self._store.delete_recorded(type, doomed)
        return deleted
