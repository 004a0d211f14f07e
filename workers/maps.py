"""The map service: assemble, check and version the explorer's maps; tell the robots; serve them.

A small map arrives inside its ``map`` event; a large one as ``map_chunk`` events followed by a
``map`` event naming them. Before a map event is stored, its image must be complete, match its
size and SHA-256, and be a valid PGM: otherwise it is dead-lettered and the stored maps do not
change. Readers fetch the latest version chunk by chunk (``map.latest``, ``map.chunk``).
"""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Awaitable, Callable, Sequence
from datetime import datetime, timezone
from typing import Any

from aio_pika.abc import AbstractExchange

from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.pgm import check_pgm
from fleetbus.schemas.routing import EventType, Topic
from fleetbus.workers.notifier import publish_notification
from fleetbus.workers.rpc import Handler, ServiceError
from fleetbus.workers.store.maps import MapStore, MapVersion
from fleetbus.workers.validation import Accepted, Rejected, RejectReason


class MapCheck:
    """Refuses map events whose image is incomplete, corrupt or not a PGM (before anything is stored)."""

    def __init__(self, maps: MapStore) -> None:
        self._maps = maps

    async def check(self, accepted: Sequence[Accepted]) -> dict[int, Rejected]:
        in_batch: dict[str, dict[int, bytes]] = {}
        refused: dict[int, Rejected] = {}
        for index, item in enumerate(accepted):
            event = item.event
            if event.type is EventType.MAP_CHUNK:
                in_batch.setdefault(str(event.body.map_id), {})[event.body.index] = event.body.data
            elif event.type is EventType.MAP and event.body.image is not None:
                if await self._maps.committed_map(event.robot_id, event.epoch, event.seq) is not None:
                    continue  # a redelivery of a map already committed
                try:
                    await assemble(self._maps, item, in_batch.get(str(event.body.image.map_id), {}))
                except ValueError as error:
                    refused[index] = Rejected(RejectReason.BAD_MAP, str(error))
        return refused


async def assemble(maps: MapStore, item: Accepted, in_batch: dict[int, bytes] | None = None) -> bytes:
    """The map event's whole image, checked; ValueError says what is wrong."""
    body = item.event.body
    if body.pgm is not None:
        return body.pgm
    image = body.image
    chunks = {**await maps.staged_map_chunks(str(image.map_id)), **(in_batch or {})}
    missing = sorted(set(range(image.chunks)) - chunks.keys())
    if missing:
        shown = ", ".join(map(str, missing[:10])) + (" ..." if len(missing) > 10 else "")
        raise ValueError(
            f"map {image.map_id}: {len(missing)} of {image.chunks} chunks missing ({shown}); "
            "chunks left without their map event expire after FLEETBUS_MAP_STAGING_TTL"
        )
    data = b"".join(chunks[i] for i in range(image.chunks))
    if len(data) != image.size:
        raise ValueError(f"map {image.map_id}: {len(data)} bytes arrived, the map event says {image.size}")
    if hashlib.sha256(data).hexdigest() != image.sha256:
        raise ValueError(f"map {image.map_id}: SHA-256 of the chunks does not match the map event")
    check_pgm(data)
    return data


class MapService:
    """After a batch is stored: stage chunks, commit maps, notify the robots of each new version."""

    def __init__(
        self,
        maps: MapStore,
        notify_exchange: AbstractExchange,
        service_user: str,
        relay: Callable[[MapVersion], Awaitable[object]] | None = None,
    ) -> None:
        self._maps = maps
        self._exchange = notify_exchange
        self._service_user = service_user
        self._relay = relay
        """Told every version a map event committed (central sends it to its sites)."""

    async def handle(self, accepted: Sequence[Accepted]) -> int:
        sent = 0
        for item in accepted:
            event = item.event
            if event.type is EventType.MAP_CHUNK:
                await self._maps.stage_map_chunk(str(event.body.map_id), event.body.index, event.body.data)
            elif event.type is EventType.MAP:
                version = await self._maps.committed_map(
                    event.robot_id, event.epoch, event.seq
                ) or await self._commit(item)
                if self._relay is not None:
                    await self._relay(version)
                note = Notification(
                    topic=Topic.MAP,
                    event=event,
                    received_at=item.record.received_at,
                    notified_at=datetime.now(timezone.utc),
                    map_version=version.version,
                )
                await publish_notification(self._exchange, note, self._service_user)
                sent += 1
        return sent

    async def _commit(self, item: Accepted) -> MapVersion:
        event = item.event
        image = await assemble(self._maps, item)
        return await self._maps.commit_map(
            event.robot_id,
            event.epoch,
            event.seq,
            image,
            event.body.metadata.model_dump(mode="json"),
            event.body.created_at,
            hashlib.sha256(image).hexdigest(),
            MAP_CHUNK_BYTES,
            str(event.body.image.map_id) if event.body.image else None,
        )


async def missing_version(maps: MapStore, version: int | None) -> str:
    """Why there is no such version: none stored yet, pruned (older than what is kept), or never made."""
    if version is None:
        return "no map has been stored yet"
    latest = await maps.map_version()
    if latest is not None and version < latest.version:
        return (
            f"map version {version} was pruned: each robot's newest maps are kept "
            "(FLEETBUS_MAP_VERSIONS_KEEP); ask for the latest"
        )
    return f"no map version {version}"


async def map_image(maps: MapStore, version: MapVersion) -> bytes:
    """A stored version's whole PGM file, read chunk by chunk."""
    return b"".join([await maps.map_chunk(version.version, index) for index in range(version.chunks)])


def map_services(maps: MapStore) -> dict[str, Handler]:
    async def latest(caller: str, params: dict[str, Any]) -> Any:
        version = params.get("version")
        if version is not None and (not isinstance(version, int) or isinstance(version, bool)):
            raise ServiceError(f"version must be an integer, not {version!r}")
        found = await maps.map_version(version)
        if found is None:
            raise ServiceError(await missing_version(maps, version))
        # a fetch begins here: the version stays while the robot reads its chunks
        await maps.note_map_read(found.version, datetime.now(timezone.utc))
        return found.as_dict()

    async def chunk(caller: str, params: dict[str, Any]) -> Any:
        version, index = params.get("version"), params.get("index")
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (version, index)):
            raise ServiceError("version and index must be non-negative integers")
        found = await maps.map_version(version)
        if found is None:
            raise ServiceError(await missing_version(maps, version))
        if index >= found.chunks:
            raise ServiceError(f"map version {version} has no chunk {index}")
        return {
            "version": version,
            "index": index,
            "data": base64.b64encode(await maps.map_chunk(version, index)).decode(),
        }

    return {"map.latest": latest, "map.chunk": chunk}
