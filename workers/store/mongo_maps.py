"""Map versions on MongoDB: staged chunks in a collection, committed images in GridFS (bucket ``maps``)."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

from bson import Binary
from gridfs import AsyncGridFSBucket
from gridfs.errors import NoFile
from pymongo import ASCENDING, DESCENDING, ReturnDocument
from pymongo.errors import DuplicateKeyError

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.maps import MapRejected, MapStore, MapVersion
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable

BUCKET = "maps"


def _map_version(doc: dict[str, Any]) -> MapVersion:
    return MapVersion(
        version=doc["_id"],
        robot_id=doc["robot_id"],
        epoch=doc["epoch"],
        seq=doc["seq"],
        metadata=doc["metadata"],
        created_at=from_micros(doc["created_at_us"]),
        size=doc["size"],
        sha256=doc["sha256"],
        chunk_size=doc["chunk_size"],
        chunks=doc["chunks"],
    )


@translate_unavailable(MapStore)
class MongoMaps(OnMongo, MapStore):
    async def create_map_indexes(self) -> None:
        await self._collection("maps").create_index(
            [("robot_id", ASCENDING), ("epoch", ASCENDING), ("seq", ASCENDING)], unique=True
        )
        await self._collection("map_staging").create_index([("map_id", ASCENDING)])

    async def stage_map_chunk(self, map_id: str, index: int, data: bytes) -> None:
        now = to_micros(datetime.now(timezone.utc))
        await self._collection("map_staging").update_one(
            {"_id": f"{map_id}:{index}"},
            {"$setOnInsert": {"map_id": map_id, "index": index, "data": Binary(data), "staged_at_us": now}},
            upsert=True,
        )

    async def staged_map_chunks(self, map_id: str) -> dict[int, bytes]:
        return {
            doc["index"]: bytes(doc["data"])
            async for doc in self._collection("map_staging").find({"map_id": map_id})
        }

    async def commit_map(
        self,
        robot_id: str,
        epoch: str,
        seq: int,
        image: bytes,
        metadata: dict[str, Any],
        created_at: datetime,
        sha256: str,
        chunk_size: int,
        staged_map_id: str | None,
    ) -> MapVersion:
        maps = self._collection("maps")
        event = {"robot_id": robot_id, "epoch": epoch, "seq": seq}
        existing = await maps.find_one(event)
        if existing is None:
            counter = await self._collection("map_counter").find_one_and_update(
                {"_id": "maps"}, {"$inc": {"last": 1}}, upsert=True, return_document=ReturnDocument.AFTER
            )
            version = counter["last"]
            bucket = AsyncGridFSBucket(self._database(), bucket_name=BUCKET, chunk_size_bytes=chunk_size)
            await bucket.upload_from_stream_with_id(
                version, f"map-{version}.pgm", image, metadata={"sha256": sha256}
            )
            existing = {
                "_id": version,
                **event,
                "metadata": metadata,
                "created_at": created_at,
                "created_at_us": to_micros(created_at),
                "size": len(image),
                "sha256": sha256,
                "chunk_size": chunk_size,
                "chunks": (len(image) + chunk_size - 1) // chunk_size,
            }
            try:
                await maps.insert_one(existing)
            except DuplicateKeyError:  # another worker committed this event first
                await bucket.delete(version)
                existing = await maps.find_one(event)
        if staged_map_id is not None:
            await self._collection("map_staging").delete_many({"map_id": staged_map_id})
        return _map_version(existing)

    async def committed_map(self, robot_id: str, epoch: str, seq: int) -> MapVersion | None:
        doc = await self._collection("maps").find_one({"robot_id": robot_id, "epoch": epoch, "seq": seq})
        return _map_version(doc) if doc else None

    async def map_version(self, version: int | None = None) -> MapVersion | None:
        maps = self._collection("maps")
        doc = await (
            maps.find_one(sort=[("_id", DESCENDING)]) if version is None else maps.find_one({"_id": version})
        )
        return _map_version(doc) if doc else None

    async def map_chunk(self, version: int, index: int) -> bytes:
        # GridFS keeps a file's n-th chunk as the document {files_id, n} of <bucket>.chunks
        doc = await self._collection(f"{BUCKET}.chunks").find_one({"files_id": version, "n": index})
        if doc is None:
            raise MapRejected(f"map version {version} has no chunk {index}")
        return bytes(doc["data"])

    async def map_versions(self) -> list[MapVersion]:
        cursor = self._collection("maps").find({}).sort("_id", DESCENDING)
        return [_map_version(doc) async for doc in cursor]

    async def note_map_read(self, version: int, at: datetime) -> None:
        await self._collection("maps").update_one({"_id": version}, {"$set": {"read_at_us": to_micros(at)}})

    async def map_reads(self) -> dict[int, datetime]:
        cursor = self._collection("maps").find({"read_at_us": {"$exists": True}}, {"read_at_us": 1})
        return {doc["_id"]: from_micros(doc["read_at_us"]) async for doc in cursor}

    async def delete_map_versions(self, versions: Sequence[int]) -> int:
        bucket = AsyncGridFSBucket(self._database(), bucket_name=BUCKET)
        deleted = 0
        for version in versions:
            # the image first: a round stopped in between leaves a description, which the next
            # round finds and deletes, never an image nothing points at
            try:
                await bucket.delete(version)
            except NoFile:  # that earlier round deleted it
                pass
            deleted += (await self._collection("maps").delete_one({"_id": version})).deleted_count
        return deleted

    async def expire_staged_chunks(self, before: datetime, limit: int) -> dict[str, int]:
        staging = self._collection("map_staging")
        pipeline = [
            {"$group": {"_id": "$map_id", "last": {"$max": "$staged_at_us"}, "chunks": {"$sum": 1}}},
            {"$match": {"last": {"$lt": to_micros(before)}}},
            {"$limit": int(limit)},
        ]
        stale = {doc["_id"]: doc["chunks"] async for doc in await staging.aggregate(pipeline)}
        if stale:
            await staging.delete_many({"map_id": {"$in": list(stale)}})
        return stale
