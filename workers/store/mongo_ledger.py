"""The sequence ledger (gaps, duplicates) on MongoDB, mixed into :class:`MongoEventStore`.

MongoDB gives no multi-document transaction on a standalone server, so the steps are ordered
to be safe if the worker dies between any two of them (the batch is then observed again):
new gap pieces are written before the gaps they replace are shrunk or deleted, and the
high-water mark moves last.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING

from workers.store.base import from_micros, to_micros
from workers.store.ledger import Duplicate, Gap, SequenceLedger, apply_seqs


def gap_id(robot_id: str, first: int) -> str:
    return f"{robot_id}:{first}"


def _gap(doc: dict[str, Any]) -> Gap:
    return Gap(doc["robot_id"], doc["first"], doc["last"], from_micros(doc["detected_at_us"]))


class MongoLedger(SequenceLedger):
    """Needs the host class's ``_collection(name)``."""

    _collection: Callable[[str], Any]

    async def create_ledger_indexes(self) -> None:
        await self._collection("sequence_gaps").create_index(
            [("robot_id", ASCENDING), ("first", ASCENDING), ("last", ASCENDING)]
        )
        await self._collection("duplicates").create_index(
            [("robot_id", ASCENDING), ("seen_at_us", DESCENDING)]
        )

    async def high_water(self, robot_id: str) -> int | None:
        doc = await self._collection("robot_sequences").find_one({"_id": robot_id})
        return doc["high_water"] if doc else None

    async def observe_sequences(self, seen: Mapping[str, Sequence[int]], at: datetime) -> None:
        gaps = self._collection("sequence_gaps")
        for robot_id, seqs in seen.items():
            if not seqs:
                continue
            high_water = await self.high_water(robot_id)
            low = min(seqs)
            touched: list[Gap] = []
            if high_water is not None and low <= high_water:
                cursor = gaps.find(
                    {
                        "robot_id": robot_id,
                        "last": {"$gte": low},
                        "first": {"$lte": min(max(seqs), high_water)},
                    }
                )
                touched = [_gap(doc) async for doc in cursor]
            change = apply_seqs(robot_id, high_water, touched, seqs, at)
            old_keys = {gap.first for gap in change.touched}
            new_keys = {gap.first for gap in change.gaps}
            for gap in sorted(change.gaps, key=lambda g: g.first in old_keys):  # new keys first
                await gaps.replace_one(
                    {"_id": gap_id(robot_id, gap.first)},
                    {
                        "robot_id": robot_id,
                        "first": gap.first,
                        "last": gap.last,
                        "detected_at": gap.detected_at,
                        "detected_at_us": to_micros(gap.detected_at),
                    },
                    upsert=True,
                )
            gone = [gap_id(robot_id, first) for first in old_keys - new_keys]
            if gone:
                await gaps.delete_many({"_id": {"$in": gone}})
            await self._collection("robot_sequences").update_one(
                {"_id": robot_id}, {"$max": {"high_water": change.high_water}}, upsert=True
            )

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
        cursor = (
            self._collection("sequence_gaps")
            .find({"robot_id": robot_id} if robot_id else {})
            .sort([("robot_id", ASCENDING), ("first", ASCENDING)])
        )
        return [_gap(doc) async for doc in cursor]

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
