"""The recording on MongoDB: one collection ``recorded.<type>`` per message type.

Each document keeps the message's body under ``document`` (so its fields are queried as
``document.<path>``) next to the provenance; ``_id`` is the record's key, which makes writes
idempotent. Documents are encoded before the write, so a body MongoDB cannot hold (an integer
beyond 64 bits, too deep, too large) is stored raw with the reason instead of failing the batch.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

import bson
from bson.binary import Binary
from bson.errors import InvalidDocument
from bson.raw_bson import RawBSONDocument
from pymongo import ASCENDING, DESCENDING
from pymongo.errors import BulkWriteError, OperationFailure

from fleetbus.defaults import DEFAULT_FIELD_INDEXES_MAX
from fleetbus.workers.store.base import StoreUnavailable, WriteResult, from_micros, to_micros
from fleetbus.workers.store.mongo import MongoStore
from fleetbus.workers.store.mongo_database import DUPLICATE_KEY, translate_unavailable
from fleetbus.workers.store.recordings import (
    Bookkeeping,
    Condition,
    Op,
    OutcomeFields,
    OutcomeStats,
    RecordedMessage,
    RecordingStore,
    RecordQuery,
    TypeSummary,
    check_digest,
    check_path,
    check_type_name,
)

log = logging.getLogger("fleetbus.recording")
COLLECTION_PREFIX = "recorded."
FIELD_INDEX_PREFIX = "f:"
#: Below MongoDB's 16 MiB document limit, with room for the provenance.
MAX_DOCUMENT_BYTES = 16 * 1024 * 1024 - 64 * 1024
MONGO_OPS = {Op.NE: "$ne", Op.LT: "$lt", Op.LE: "$lte", Op.GT: "$gt", Op.GE: "$gte"}


BLOB_BUCKET = "recording_blobs"
"""The GridFS bucket of the recording's large values, each file named by its digest."""


def collection_name(type: str) -> str:
    return COLLECTION_PREFIX + check_type_name(type)


def field(path: str) -> str:
    check_path(path)
    return f"document.{path}"


def condition_filter(condition: Condition) -> dict[str, Any]:
    """The condition as the SQLite store reads it (:mod:`.sqlite_recordings`, a JSON path): a path
    names one value, so it goes through no array (``tags=red`` does not match ``["red"]``, nor
    ``items.name=a`` ``[{"name": "a"}]``, as MongoDB's own matching would), and a digit segment
    is an array's index only (not an object's key ``"1"``)."""
    name, value = field(condition.path), condition.value
    if condition.op is Op.EQ and value is None:
        return {"$nor": [_resolves(condition.path)]}
    if condition.op is Op.NE and value is None:
        return _resolves(condition.path)
    if condition.op is Op.EQ:
        return _scalar_at(condition.path, {name: value})
    if condition.op is Op.NE:
        return {"$nor": [_scalar_at(condition.path, {name: value})]}
    if condition.op is Op.CONTAINS:
        return _scalar_at(condition.path, {name: {"$regex": re.escape(str(value))}})
    # MongoDB orders within one type only; saying so keeps every engine to it
    kind = "string" if isinstance(value, str) else "number"
    return _scalar_at(condition.path, {name: {MONGO_OPS[condition.op]: value, "$type": kind}})


def _on_the_path(path: str) -> list[dict[str, Any]]:
    """What each step of ``path`` stands on: an array before an index, anything else before a name."""
    segments = check_path(path)
    steps = []
    for depth in range(len(segments)):
        parent = field(".".join(segments[:depth])) if depth else "document"
        array = {"$type": "array"}
        steps.append({parent: array if segments[depth].isdigit() else {"$not": array}})
    return steps


def _scalar_at(path: str, test: dict[str, Any]) -> dict[str, Any]:
    """``test`` of the one value at ``path``, itself no array."""
    return {"$and": [*_on_the_path(path), {field(path): {"$not": {"$type": "array"}}}, test]}


def _resolves(path: str) -> dict[str, Any]:
    """``path`` names a value that is not null (an array counts)."""
    name = field(path)
    present = {"$or": [{name: {"$type": "array"}}, {name: {"$exists": True, "$ne": None}}]}
    return {"$and": [*_on_the_path(path), present]}


def provenance_filter(
    robot_id: str | None = None,
    message_id: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
) -> list[dict[str, Any]]:
    filters: list[dict[str, Any]] = []
    if robot_id is not None:
        filters.append({"robot_id": robot_id})
    if message_id is not None:
        filters.append({"message_id": message_id})
    window: dict[str, int] = {}
    if since is not None:
        window["$gte"] = to_micros(since)
    if until is not None:
        window["$lt"] = to_micros(until)
    if window:
        filters.append({"recorded_at_us": window})
    return filters


def all_of(filters: list[dict[str, Any]]) -> dict[str, Any]:
    return {"$and": filters} if filters else {}


def to_document(record: RecordedMessage) -> dict[str, Any]:
    return {
        "_id": record.key,
        "recorded_at": record.recorded_at,
        "recorded_at_us": to_micros(record.recorded_at),
        "exchange": record.exchange,
        "routing_key": record.routing_key,
        "user_id": record.user_id,
        "robot_id": record.robot_id,
        "message_id": record.message_id,
        "mission_id": record.mission_id,
        "sent_at_us": to_micros(record.sent_at) if record.sent_at else None,
        "seq": record.seq,
        "known": record.known,
        "problem": record.problem,
        "document": record.document,
        "raw": Binary(record.raw) if record.raw is not None else None,
        "properties": record.properties,
        "size": record.size,
    }


def encode(record: RecordedMessage) -> RawBSONDocument:
    """The record as BSON; a body MongoDB cannot hold is kept raw (or, if too large, left out)."""
    try:
        encoded = bson.encode(to_document(record))
    except (InvalidDocument, OverflowError, RecursionError) as error:
        raw = record.body_bytes() or b""
        return encode(record.as_raw(f"not storable as a MongoDB document ({error}); kept raw", raw))
    if len(encoded) > MAX_DOCUMENT_BYTES:
        if record.document is None and record.raw is None:
            raise ValueError(f"record {record.key} is too large even without its body")
        return encode(
            record.as_raw(f"larger than a MongoDB document ({len(encoded)} bytes); body not kept", b"")
        )
    return RawBSONDocument(encoded)


def from_document(type: str, doc: dict[str, Any]) -> RecordedMessage:
    raw = doc.get("raw")
    return RecordedMessage(
        key=doc["_id"],
        type=type,
        recorded_at=from_micros(doc["recorded_at_us"]),
        exchange=doc["exchange"],
        routing_key=doc["routing_key"],
        user_id=doc.get("user_id"),
        robot_id=doc.get("robot_id"),
        message_id=doc.get("message_id"),
        mission_id=doc.get("mission_id"),
        sent_at=from_micros(doc["sent_at_us"]) if doc.get("sent_at_us") is not None else None,
        seq=doc.get("seq"),
        known=bool(doc.get("known")),
        problem=doc.get("problem"),
        document=doc.get("document"),
        raw=bytes(raw) if raw is not None else None,
        properties=doc.get("properties") or {},
        size=doc.get("size", 0),
    )


@translate_unavailable(RecordingStore)
class MongoRecordingStore(MongoStore, RecordingStore):
    name = "mongodb"

    def __init__(
        self,
        url: str,
        database: str | None = None,
        server_selection_timeout: float = 5.0,
        max_field_indexes: int = DEFAULT_FIELD_INDEXES_MAX,
    ) -> None:
        super().__init__(url, database, server_selection_timeout)
        self._indexed: set[str] = set()
        self.bookkeeping = Bookkeeping(self, max_field_indexes)

    def _blobs(self) -> Any:
        from gridfs import AsyncGridFSBucket

        return AsyncGridFSBucket(self._database(), bucket_name=BLOB_BUCKET)

    async def put_blob(self, digest: str, data: bytes) -> bool:
        check_digest(digest)
        bucket = self._blobs()
        if await self._database()[f"{BLOB_BUCKET}.files"].find_one({"filename": digest}, {"_id": 1}):
            return False
        await bucket.upload_from_stream(digest, data)
        return True

    async def get_blob(self, digest: str) -> bytes | None:
        from gridfs.errors import NoFile

        try:
            stream = await self._blobs().open_download_stream_by_name(check_digest(digest))
        except NoFile:
            return None
        data: bytes = await stream.read()
        return data

    async def delete_blobs(self, digests: Sequence[str]) -> int:
        from gridfs.errors import NoFile

        files = self._database()[f"{BLOB_BUCKET}.files"]
        bucket = self._blobs()
        deleted = 0
        async for found in files.find({"filename": {"$in": [check_digest(d) for d in digests]}}, {"_id": 1}):
            try:
                await bucket.delete(found["_id"])
                deleted += 1
            except NoFile:  # another process deleted it meanwhile
                pass
        return deleted

    def _recorded(self, type: str) -> Any:
        return self._collection(collection_name(type))

    async def _ensure_collection(self, type: str) -> None:
        """The standard indexes of a type, once per type and process (creating them is idempotent)."""
        if type in self._indexed:
            return
        collection = self._recorded(type)
        await collection.create_index([("recorded_at_us", ASCENDING), ("_id", ASCENDING)])
        await collection.create_index([("robot_id", ASCENDING), ("recorded_at_us", ASCENDING)])
        await collection.create_index([("message_id", ASCENDING)])
        await collection.create_index([("mission_id", ASCENDING), ("recorded_at_us", ASCENDING)])
        self._indexed.add(type)

    async def _write_records(self, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        by_type: dict[str, list[int]] = {}
        for index, record in enumerate(records):
            by_type.setdefault(record.type, []).append(index)
        duplicates: set[int] = set()
        for type, indexes in by_type.items():
            await self._ensure_collection(type)
            duplicates |= await self._insert(type, [records[i] for i in indexes], indexes)
        return [WriteResult(inserted=index not in duplicates) for index in range(len(records))]

    async def _insert(self, type: str, records: list[RecordedMessage], indexes: list[int]) -> set[int]:
        """Insert one type's records; the batch indexes of those already stored."""
        try:
            await self._recorded(type).insert_many([encode(record) for record in records], ordered=False)
        except BulkWriteError as error:
            if error.details.get("writeConcernErrors"):
                raise self._not_durable(error) from error
            duplicates: set[int] = set()
            refused: list[int] = []
            for problem in error.details.get("writeErrors", []):
                (duplicates.add if problem.get("code") == DUPLICATE_KEY else refused.append)(problem["index"])
            for position in refused:  # the server would not take the body as a document (e.g. '$' keys)
                record = records[position]
                reason = next(e["errmsg"] for e in error.details["writeErrors"] if e["index"] == position)
                raw = record.body_bytes() or b""
                await self._recorded(type).insert_one(
                    encode(record.as_raw(f"refused as a MongoDB document ({reason}); kept raw", raw))
                )
            return {indexes[position] for position in duplicates}
        return set()

    def _not_durable(self, error: BulkWriteError) -> Exception:
        return StoreUnavailable(
            f"MongoDB at {self._safe_url()}: write concern not met: {error.details['writeConcernErrors']}"
        )

    async def find_recorded(self, query: RecordQuery) -> list[RecordedMessage]:
        filters = provenance_filter(query.robot_id, query.message_id, query.since, query.until)
        if query.mission_id is not None:
            filters.append({"mission_id": query.mission_id})
        if query.after is not None:
            at, key = to_micros(query.after[0]), query.after[1]
            filters.append(
                {"$or": [{"recorded_at_us": {"$gt": at}}, {"recorded_at_us": at, "_id": {"$gt": key}}]}
            )
        filters.extend(condition_filter(condition) for condition in query.conditions)
        direction = DESCENDING if query.newest_first else ASCENDING
        cursor = (
            self._recorded(query.type)
            .find(all_of(filters))
            .sort([("recorded_at_us", direction), ("_id", direction)])
        )
        if query.limit is not None:
            cursor = cursor.limit(query.limit)
        return [from_document(query.type, doc) async for doc in cursor]

    async def recorded_types(self) -> list[str]:
        names = await self._database().list_collection_names()
        return sorted(name[len(COLLECTION_PREFIX) :] for name in names if name.startswith(COLLECTION_PREFIX))

    async def type_summary(self, type: str) -> TypeSummary:
        pipeline = [
            {
                "$group": {
                    "_id": None,
                    "records": {"$sum": 1},
                    "bytes": {"$sum": "$size"},
                    "first": {"$min": "$recorded_at_us"},
                    "last": {"$max": "$recorded_at_us"},
                }
            }
        ]
        rows = [row async for row in await self._recorded(type).aggregate(pipeline)]
        if not rows:
            return TypeSummary(type, 0, 0, None, None)
        row = rows[0]
        return TypeSummary(
            type, row["records"], row["bytes"], from_micros(row["first"]), from_micros(row["last"])
        )

    async def ensure_field_index(self, type: str, paths: Sequence[str]) -> None:
        keys = [(field(path), ASCENDING) for path in paths] + [("recorded_at_us", ASCENDING)]
        name = FIELD_INDEX_PREFIX + ",".join(paths)
        await self._ensure_collection(type)
        now = datetime.now(timezone.utc)
        if await self.bookkeeping.used(type, name, now):
            return
        # a new shape: make room by dropping the least recently used
        recorded = self._recorded(type)
        for old, old_paths in await self.bookkeeping.make_room(type):
            if old in await recorded.index_information():
                await recorded.drop_index(old)
            log.info("%s: dropped the least recently used field index %s", type, old_paths)
        try:
            await recorded.create_index(keys, name=name)
        except OperationFailure as error:  # e.g. another process filled the last slots: query unindexed
            log.warning("%s: no field index on %s (%s); the query runs without one", type, paths, error)
            return
        await self.bookkeeping.made(type, name, paths, now)

    async def outcome_stats(
        self,
        type: str,
        fields: OutcomeFields,
        since: datetime | None = None,
        until: datetime | None = None,
        robot_id: str | None = None,
    ) -> list[OutcomeStats]:
        name, success, duration = (
            f"${field(path)}" for path in (fields.name, fields.success, fields.duration)
        )
        mean = {"$divide": ["$total", "$runs"]}
        pipeline = [
            {
                "$match": all_of(
                    [
                        {field(fields.name): {"$type": "string"}},
                        {field(fields.duration): {"$type": "number"}},
                        *provenance_filter(robot_id, None, since, until),
                    ]
                )
            },
            {
                "$group": {
                    "_id": name,
                    "successes": {"$sum": {"$cond": [{"$eq": [success, True]}, 1, 0]}},
                    "runs": {"$sum": 1},
                    "total": {"$sum": duration},
                    "squares": {"$sum": {"$multiply": [duration, duration]}},
                }
            },
            {
                "$project": {
                    "successes": 1,
                    "runs": 1,
                    "mean": mean,
                    "std": {
                        "$sqrt": {
                            "$max": [
                                0,
                                {
                                    "$subtract": [
                                        {"$divide": ["$squares", "$runs"]},
                                        {"$multiply": [mean, mean]},
                                    ]
                                },
                            ]
                        }
                    },
                }
            },
            {"$sort": {"_id": 1}},
        ]
        rows = [row async for row in await self._recorded(type).aggregate(pipeline)]
        return [
            OutcomeStats.of(row["_id"], row["successes"], row["runs"], row["mean"], row["std"])
            for row in rows
        ]

    async def _delete_records_before(self, type: str, before: datetime) -> int:
        result = await self._recorded(type).delete_many({"recorded_at_us": {"$lt": to_micros(before)}})
        return result.deleted_count

    async def oldest_recorded(self, type: str, limit: int) -> list[tuple[str, int]]:
        cursor = (
            self._recorded(type)
            .find({}, {"_id": 1, "size": 1})
            .sort([("recorded_at_us", ASCENDING), ("_id", ASCENDING)])
            .limit(int(limit))
        )
        return [(doc["_id"], doc.get("size", 0)) async for doc in cursor]

    async def _delete_records(self, type: str, keys: Sequence[str]) -> int:
        if not keys:
            return 0
        result = await self._recorded(type).delete_many({"_id": {"$in": list(keys)}})
        return result.deleted_count

    async def database_bytes(self) -> int:
        total = 0
        for type in await self.recorded_types():
            stats = await self._database().command("collStats", collection_name(type))
            total += int(stats.get("storageSize", 0)) + int(stats.get("totalIndexSize", 0))
        return total + await self._blob_bytes()

    async def _blob_bytes(self) -> int:
        """The blobs' bytes, as GridFS notes each file's length (the chunks' storage size lags:
        the server updates it at its checkpoints)."""
        pipeline = [{"$group": {"_id": None, "bytes": {"$sum": "$length"}}}]
        rows = [row async for row in await self._database()[f"{BLOB_BUCKET}.files"].aggregate(pipeline)]
        return int(rows[0]["bytes"]) if rows else 0
