"""Map storage: every version of the team's map, its image kept in chunks.

Large images arrive as chunks, which wait in a staging area until the ``map`` event that names
them commits a new version: on SQLite into a blob table, on MongoDB into GridFS. Readers fetch a
version's image chunk by chunk, so no message or reply ever carries the whole file.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from workers.store.base import StoreError


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
