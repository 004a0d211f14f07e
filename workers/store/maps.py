"""Map storage: every version of the team's map, its image kept in chunks.

Large images arrive as chunks, which wait in a staging area until the ``map`` event that names
them commits a new version, its image kept as chunks of its own. Readers fetch a version's image
chunk by chunk, so no message or reply ever carries the whole file.

Both grow with time and are bounded (:func:`versions_to_prune`, :meth:`MapStore.expire_staged_chunks`):
each robot's newest versions are kept, and so is any version a robot began to fetch lately;
staged chunks whose map event never came expire.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from fleetbus.workers.store.base import StoreError
from fleetbus.workers.store.port import (
    BYTES,
    COUNTERS,
    INTEGER,
    JSON,
    TEXT,
    TIME,
    Database,
    Doc,
    In,
    Index,
    Ne,
    Schema,
    next_number,
)


@dataclass(frozen=True)
class MapVersion:
    version: int
    robot_id: str
    epoch: str
    seq: int
    metadata: dict[str, Any]
    created_at: datetime
    size: int
    sha256: str
    chunk_size: int
    chunks: int

    def as_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["created_at"] = self.created_at.isoformat()
        return out


class MapRejected(StoreError):
    """The map cannot be committed (chunks missing, checksum wrong); the message says which."""


class MapStore(abc.ABC):
    @abc.abstractmethod
    async def stage_map_chunk(self, map_id: str, index: int, data: bytes) -> None:
        """Keep one chunk of an image until its map is committed; idempotent."""

    @abc.abstractmethod
    async def staged_map_chunks(self, map_id: str) -> dict[int, bytes]: ...

    @abc.abstractmethod
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
        """Store ``image`` as the next version (idempotent on the map event's robot, epoch and seq);
        drop the staged chunks."""

    @abc.abstractmethod
    async def committed_map(self, robot_id: str, epoch: str, seq: int) -> MapVersion | None:
        """The version the map event (robot_id, epoch, seq) committed, if it did."""

    @abc.abstractmethod
    async def map_version(self, version: int | None = None) -> MapVersion | None:
        """A version's description; the latest when ``version`` is None."""

    @abc.abstractmethod
    async def map_chunk(self, version: int, index: int) -> bytes:
        """One chunk of a version's image (``chunk_size`` bytes, the last one shorter)."""

    @abc.abstractmethod
    async def map_versions(self) -> list[MapVersion]:
        """Every stored version, newest first."""

    @abc.abstractmethod
    async def note_map_read(self, version: int, at: datetime) -> None:
        """A robot began to fetch ``version`` (``map.latest``): it is referenced for a while."""

    @abc.abstractmethod
    async def map_reads(self) -> dict[int, datetime]:
        """When each version was last begun to be fetched (versions never fetched are absent)."""

    @abc.abstractmethod
    async def delete_map_versions(self, versions: Sequence[int]) -> int:
        """Delete these versions and their images; how many were there."""

    @abc.abstractmethod
    async def expire_staged_chunks(self, before: datetime, limit: int) -> dict[str, int]:
        """Delete the staged chunks of up to ``limit`` maps whose last chunk was staged before
        ``before`` (their map event never came); chunks deleted, by map id."""


def versions_to_prune(
    versions: Sequence[MapVersion], reads: Mapping[int, datetime], keep: int, read_since: datetime
) -> list[int]:
    """The versions beyond each robot's ``keep`` newest that no robot began to fetch since
    ``read_since``, oldest first."""
    seen: dict[str, int] = {}
    doomed = []
    for version in sorted(versions, key=lambda v: v.version, reverse=True):
        seen[version.robot_id] = seen.get(version.robot_id, 0) + 1
        read = reads.get(version.version)
        if seen[version.robot_id] > keep and (read is None or read < read_since):
            doomed.append(version.version)
    return sorted(doomed)


STAGED = Schema(
    "map_staging",
    {"map_id": TEXT, "index": INTEGER, "data": BYTES, "staged_at": TIME},
    key=("map_id", "index"),
    indexes=(Index("map_id"),),
)
MAPS = Schema(
    "maps",
    {
        "version": INTEGER,
        "robot_id": TEXT,
        "epoch": TEXT,
        "seq": INTEGER,
        "metadata": JSON,
        "created_at": TIME,
        "size": INTEGER,
        "sha256": TEXT,
        "chunk_size": INTEGER,
        "chunks": INTEGER,
        "read_at": TIME.maybe,
    },
    key=("version",),
    indexes=(Index("robot_id", "epoch", "seq", unique=True), Index("read_at")),
)
"""A version's description; its image is in :data:`MAP_CHUNKS`, one document per chunk."""
MAP_CHUNKS = Schema(
    "map_chunks",
    {"version": INTEGER, "index": INTEGER, "data": BYTES},
    key=("version", "index"),
    indexes=(Index("version"),),
)
DESCRIPTION = [name for name in MAPS.fields if name != "read_at"]


def _version(doc: Doc) -> MapVersion:
    return MapVersion(**{name: doc[name] for name in DESCRIPTION})


class Maps(MapStore):
    """A version's number comes from a counter, so a pruned version's number is never given again.
    Its chunks are written before its description, so a description always has its image."""

    def __init__(self, database: Database) -> None:
        self._database = database
        self._staged = database.collection(STAGED)
        self._maps = database.collection(MAPS)
        self._chunks = database.collection(MAP_CHUNKS)
        self._counters = database.collection(COUNTERS)

    async def stage_map_chunk(self, map_id: str, index: int, data: bytes) -> None:
        now = datetime.now(timezone.utc)
        await self._staged.insert([{"map_id": map_id, "index": index, "data": data, "staged_at": now}])

    async def staged_map_chunks(self, map_id: str) -> dict[int, bytes]:
        return {doc["index"]: doc["data"] for doc in await self._staged.find({"map_id": map_id})}

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
        event = {"robot_id": robot_id, "epoch": epoch, "seq": seq}
        pieces = [image[i : i + chunk_size] for i in range(0, len(image), chunk_size)]

        async def commit() -> MapVersion:
            found = await self._maps.find(event, fields=DESCRIPTION)
            if not found:
                version = await next_number(self._counters, MAPS.name)
                await self._chunks.insert(
                    [{"version": version, "index": i, "data": piece} for i, piece in enumerate(pieces)]
                )
                description = {
                    "version": version,
                    **event,
                    "metadata": metadata,
                    "created_at": created_at,
                    "size": len(image),
                    "sha256": sha256,
                    "chunk_size": chunk_size,
                    "chunks": len(pieces),
                    "read_at": None,
                }
                if (await self._maps.insert([description]))[0]:
                    found = [description]
                else:  # another worker committed this event first
                    await self._chunks.delete({"version": version})
                    found = await self._maps.find(event, fields=DESCRIPTION)
            if staged_map_id is not None:
                await self._staged.delete({"map_id": staged_map_id})
            return _version(found[0])

        return await self._database.transaction(commit)

    async def committed_map(self, robot_id: str, epoch: str, seq: int) -> MapVersion | None:
        found = await self._maps.find({"robot_id": robot_id, "epoch": epoch, "seq": seq}, fields=DESCRIPTION)
        return _version(found[0]) if found else None

    async def map_version(self, version: int | None = None) -> MapVersion | None:
        where = {} if version is None else {"version": version}
        found = await self._maps.find(where, order=["-version"], limit=1, fields=DESCRIPTION)
        return _version(found[0]) if found else None

    async def map_chunk(self, version: int, index: int) -> bytes:
        chunk = await self._chunks.get(version, index)
        if chunk is None:
            raise MapRejected(f"map version {version} has no chunk {index}")
        data: bytes = chunk["data"]
        return data

    async def map_versions(self) -> list[MapVersion]:
        return [_version(doc) for doc in await self._maps.find(order=["-version"], fields=DESCRIPTION)]

    async def note_map_read(self, version: int, at: datetime) -> None:
        await self._maps.update({"version": version}, {"read_at": at})

    async def map_reads(self) -> dict[int, datetime]:
        found = await self._maps.find({"read_at": Ne(None)}, fields=["version", "read_at"])
        return {doc["version"]: doc["read_at"] for doc in found}

    async def delete_map_versions(self, versions: Sequence[int]) -> int:
        async def delete() -> int:
            # the image first: a round stopped in between leaves a description, which the next
            # round finds and deletes, never an image nothing points at
            deleted = 0
            for version in versions:
                await self._chunks.delete({"version": version})
                deleted += await self._maps.delete({"version": version})
            return deleted

        return await self._database.transaction(delete) if versions else 0

    async def expire_staged_chunks(self, before: datetime, limit: int) -> dict[str, int]:
        async def expire() -> dict[str, int]:
            maps = await self._staged.group("map_id", highest=["staged_at"])
            stale = sorted(map_id for map_id, group in maps.items() if group.highest["staged_at"] < before)
            stale = stale[: int(limit)]
            if stale:
                await self._staged.delete({"map_id": In(stale)})
            return {map_id: maps[map_id].count for map_id in stale}

        return await self._database.transaction(expire)
