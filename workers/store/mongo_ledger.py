"""The sequence ledger (gaps, duplicates) on MongoDB, mixed into :class:`MongoEventStore`.

One document per robot holds its high-water mark and its gaps, with a version: an observation
reads it, works out the change, and writes it back only if the version is still the one it read
(else it reads again). One document is written atomically without a transaction, so the express
lane and a shard (two worker processes when the shards are shared) can observe the same robot at
once without losing an update, and a worker that dies mid-way leaves the ledger as it was.

Before this layout, each gap was a document of ``sequence_gaps`` and the robot's document held
only its mark: such a robot's gaps are read from there, and moved into its document the first
time it is observed again.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING
from pymongo.errors import DuplicateKeyError

from workers.store.base import from_micros, to_micros
from workers.store.ledger import Duplicate, Gap, SequenceLedger, apply_seqs


def _gap(robot_id: str, doc: dict[str, Any]) -> Gap:
    return Gap(robot_id, doc["first"], doc["last"], from_micros(doc["detected_at_us"]))


def _stored(gap: Gap) -> dict[str, Any]:
    return {"first": gap.first, "last": gap.last, "detected_at_us": to_micros(gap.detected_at)}


class MongoLedger(SequenceLedger):
    """Needs the host class's ``_collection(name)``."""

    _collection: Callable[[str], Any]

    async def create_ledger_indexes(self) -> None:
        await self._collection("duplicates").create_index(
            [("robot_id", ASCENDING), ("seen_at_us", DESCENDING)]
        )

    async def high_water(self, robot_id: str) -> int | None:
        doc = await self._collection("robot_sequences").find_one({"_id": robot_id})
        return doc["high_water"] if doc else None

    async def observe_sequences(self, seen: Mapping[str, Sequence[int]], at: datetime) -> None:
        for robot_id, seqs in seen.items():
            if seqs:
                while not await self._observe(robot_id, seqs, at):
                    pass  # another observer changed the robot's ledger meanwhile: again, from it

    async def _observe(self, robot_id: str, seqs: Sequence[int], at: datetime) -> bool:
        """One attempt; False if another observer wrote the robot's document first."""
        robots = self._collection("robot_sequences")
        doc = await robots.find_one({"_id": robot_id})
        high_water = doc["high_water"] if doc else None
        legacy = doc is not None and "version" not in doc
        gaps = await self._gaps_of(robot_id, doc)
        low, high = min(seqs), max(seqs)
        touched = [
            g for g in gaps if high_water is not None and g.last >= low and g.first <= min(high, high_water)
        ]
        change = apply_seqs(robot_id, high_water, touched, seqs, at)
        kept = [g for g in gaps if g not in touched]
        after = {
            "high_water": change.high_water,
            "gaps": [_stored(g) for g in sorted([*kept, *change.gaps], key=lambda g: g.first)],
        }
        if doc is None:
            try:
                await robots.insert_one({"_id": robot_id, **after, "version": 1})
            except DuplicateKeyError:
                return False
            return True
        version = {"$exists": False} if legacy else doc["version"]
        written = await robots.update_one(
            {"_id": robot_id, "version": version}, {"$set": after, "$inc": {"version": 1}}
        )
        if written.matched_count == 0:
            return False
        if legacy:
            await self._collection("sequence_gaps").delete_many({"robot_id": robot_id})
        return True

    async def _gaps_of(self, robot_id: str, doc: dict[str, Any] | None) -> list[Gap]:
        """The robot's gaps: in its document, or (a document without a version, from before this
        layout) one document each in ``sequence_gaps``."""
        if doc is not None and "version" not in doc:
            cursor = self._collection("sequence_gaps").find({"robot_id": robot_id})
            return [_gap(robot_id, gap) async for gap in cursor]
        return [_gap(robot_id, gap) for gap in (doc or {}).get("gaps", [])]

    async def record_duplicates(self, duplicates: Sequence[Duplicate]) -> None:
        if duplicates:
            await self._collection("duplicates").insert_many(
                [
                    {
                        "robot_id": d.robot_id,
                        "seq": d.seq,
                        "message_id": d.message_id,
                        "seen_at": d.seen_at,
                        "seen_at_us": to_micros(d.seen_at),
                        "redelivered": d.redelivered,
                    }
                    for d in duplicates
                ]
            )

    async def gaps(self, robot_id: str | None = None) -> list[Gap]:
        found: list[Gap] = []
        async for doc in self._collection("robot_sequences").find({"_id": robot_id} if robot_id else {}):
            found.extend(await self._gaps_of(doc["_id"], doc))
        return sorted(found, key=lambda gap: (gap.robot_id, gap.first))

    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        cursor = (
            self._collection("duplicates")
            .find({"robot_id": robot_id} if robot_id else {})
            .sort([("seen_at_us", DESCENDING), ("robot_id", ASCENDING), ("seq", DESCENDING)])
        )
        if limit is not None:
            cursor = cursor.limit(limit)
        return [
            Duplicate(
                d["robot_id"], d["seq"], d["message_id"], from_micros(d["seen_at_us"]), d["redelivered"]
            )
            async for d in cursor
        ]
