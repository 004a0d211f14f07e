"""Map storage: every version of the team's map, its image kept in chunks.

Large images arrive as chunks, which wait in a staging area until the ``map`` event that names
them commits a new version: on SQLite into a blob table, on MongoDB into GridFS. Readers fetch a
version's image chunk by chunk, so no message or reply ever carries the whole file.

Both grow with time and are bounded (:func:`versions_to_prune`, :meth:`MapStore.expire_staged_chunks`):
each robot's newest versions are kept, and so is any version a robot began to fetch lately;
staged chunks whose map event never came expire.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fleetbus.workers.store.base import StoreError


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
