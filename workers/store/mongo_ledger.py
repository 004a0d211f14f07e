"""The sequence ledger (gaps, duplicates) on MongoDB, one repository of `mongo_repositories`.

One document per robot and epoch (``_id`` ``<robot>:<epoch>``) holds its high-water mark and its
gaps, with a version: an observation reads it, works out the change, and writes it back only if
the version is still the one it read (else it reads again). One document is written atomically
without a transaction, so the express lane and a shard (two worker processes when the shards are
shared) can observe the same numbering at once without losing an update, and a worker that dies
mid-way leaves the ledger as it was.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime
from typing import Any

from pymongo import ASCENDING, DESCENDING
from pymongo.errors import DuplicateKeyError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.ledger import (
    Duplicate,
    Gap,
    RobotEpoch,
    SequenceLedger,
    apply_seqs,
    seen_numbers,
)
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable


def numbering_id(numbering: RobotEpoch) -> str:
    return f"{numbering.robot_id}:{numbering.epoch}"


def _gap(numbering: RobotEpoch, doc: dict[str, Any]) -> Gap:
    return Gap(*numbering, doc["first"], doc["last"], from_micros(doc["detected_at_us"]))


def _gaps_of(doc: dict[str, Any]) -> list[Gap]:
    numbering = RobotEpoch(doc["robot_id"], doc["epoch"])
    return [_gap(numbering, gap) for gap in doc.get("gaps", [])]


def _stored(gap: Gap) -> dict[str, Any]:
    return {"first": gap.first, "last": gap.last, "detected_at_us": to_micros(gap.detected_at)}


@translate_unavailable(SequenceLedger)
class MongoLedger(OnMongo, SequenceLedger):
    async def create_ledger_indexes(self) -> None:
        await self._collection("robot_sequences").create_index(
            [("robot_id", ASCENDING), ("epoch", ASCENDING)]
        )
        await self._collection("duplicates").create_index(
            [("robot_id", ASCENDING), ("seen_at_us", DESCENDING)]
        )

    async def high_water(self, robot_id: str, epoch: str) -> int | None:
        doc = await self._collection("robot_sequences").find_one(
            {"_id": numbering_id(RobotEpoch(robot_id, epoch))}
        )
        return doc["high_water"] if doc else None

    async def _observed(self, wanted: Mapping[RobotEpoch, Sequence[int]]) -> set[tuple[str, str, int]]:
        """The (robot, epoch, seq) keys of ``wanted`` the ledger has seen."""
        if not wanted:
            return set()
        ids = [numbering_id(RobotEpoch(*numbering)) for numbering in wanted]
        docs = self._collection("robot_sequences").find({"_id": {"$in": ids}})
        keys: set[tuple[str, str, int]] = set()
        async for doc in docs:
            numbering = RobotEpoch(doc["robot_id"], doc["epoch"])
            seqs = wanted[numbering]
            keys.update((*numbering, seq) for seq in seen_numbers(doc["high_water"], _gaps_of(doc), seqs))
        return keys

    async def observe_sequences(self, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
        for numbering, seqs in seen.items():
            if seqs:
                while not await self._observe(RobotEpoch(*numbering), seqs, at):
                    pass  # another observer changed this numbering's ledger meanwhile: again, from it

    async def _observe(self, numbering: RobotEpoch, seqs: Sequence[int], at: datetime) -> bool:
        """One attempt; False if another observer wrote the numbering's document first."""
        robots = self._collection("robot_sequences")
        doc = await robots.find_one({"_id": numbering_id(numbering)})
        high_water = doc["high_water"] if doc else None
        gaps = _gaps_of(doc) if doc else []
        low, high = min(seqs), max(seqs)
        touched = [
            g for g in gaps if high_water is not None and g.last >= low and g.first <= min(high, high_water)
        ]
        change = apply_seqs(numbering, high_water, touched, seqs, at)
        kept = [g for g in gaps if g not in touched]
        after = {
            "high_water": change.high_water,
            "gaps": [_stored(g) for g in sorted([*kept, *change.gaps], key=lambda g: g.first)],
        }
        if doc is None:
            try:
                await robots.insert_one(
                    {"_id": numbering_id(numbering), **numbering._asdict(), **after, "version": 1}
                )
            except DuplicateKeyError:
                return False
            return True
        written = await robots.update_one(
            {"_id": doc["_id"], "version": doc["version"]}, {"$set": after, "$inc": {"version": 1}}
        )
        return written.matched_count == 1

    async def record_duplicates(self, duplicates: Sequence[Duplicate]) -> None:
        if duplicates:
            await self._collection("duplicates").insert_many(
                [
                    {
                        "robot_id": d.robot_id,
                        "epoch": d.epoch,
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
        async for doc in self._collection("robot_sequences").find({"robot_id": robot_id} if robot_id else {}):
            found.extend(_gaps_of(doc))
        return sorted(found, key=lambda gap: (gap.robot_id, gap.epoch, gap.first))

    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        cursor = (
            self._collection("duplicates")
            .find({"robot_id": robot_id} if robot_id else {})
            .sort(
                [
                    ("seen_at_us", DESCENDING),
                    ("robot_id", ASCENDING),
                    ("epoch", DESCENDING),
                    ("seq", DESCENDING),
                ]
            )
        )
        if limit is not None:
            cursor = cursor.limit(limit)
        return [
            Duplicate(
                d["robot_id"],
                d["epoch"],
                d["seq"],
                d["message_id"],
                from_micros(d["seen_at_us"]),
                d["redelivered"],
            )
            async for d in cursor
        ]
