"""Maps on the robot side: split a large PGM into chunk events, and fetch a stored map back."""

from __future__ import annotations

import base64
import hashlib
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Protocol

from fleetbus.schemas.bodies import MAP_INLINE_BYTES, MapMetadata, split_chunks
from fleetbus.schemas.pgm import check_pgm
from fleetbus.schemas.routing import EventType


def map_events(
    pgm: bytes, metadata: MapMetadata | dict[str, Any], created_at: datetime | None = None
) -> list[tuple[EventType, dict[str, Any]]]:
    """The events that publish a map: one ``map`` event, preceded by ``map_chunk`` events when large."""
    check_pgm(pgm)  # fail on the robot, before anything is sent
    meta = metadata if isinstance(metadata, MapMetadata) else MapMetadata.model_validate(metadata)
    body: dict[str, Any] = {
        "metadata": meta.model_dump(mode="json"),
        "created_at": (created_at or datetime.now(timezone.utc)).isoformat(),
    }
    if len(pgm) <= MAP_INLINE_BYTES:
        return [(EventType.MAP, {**body, "pgm": base64.b64encode(pgm).decode()})]
    map_id = str(uuid.uuid4())
    pieces = split_chunks(pgm)
    count = len(pieces)
    chunks = [
        (
            EventType.MAP_CHUNK,
            {"map_id": map_id, "index": i, "count": count, "data": base64.b64encode(piece).decode()},
        )
        for i, piece in enumerate(pieces)
    ]
    image = {"map_id": map_id, "size": len(pgm), "sha256": hashlib.sha256(pgm).hexdigest(), "chunks": count}
    return [*chunks, (EventType.MAP, {**body, "image": image})]


class Caller(Protocol):
    def call(self, method: str, timeout: float = 5.0, **params: Any) -> Any: ...


@dataclass(frozen=True)
class FetchedMap:
    version: int
    pgm: bytes
    metadata: dict[str, Any]
    created_at: str
    robot_id: str


def fetch_map(client: Caller, version: int | None = None, timeout: float = 10.0) -> FetchedMap:
    """The latest (or a given) map version, fetched chunk by chunk and checked against its SHA-256."""
    info = client.call("map.latest", timeout, version=version)
    pieces = [
        base64.b64decode(client.call("map.chunk", timeout, version=info["version"], index=i)["data"])
        for i in range(info["chunks"])
    ]
    pgm = b"".join(pieces)
    if hashlib.sha256(pgm).hexdigest() != info["sha256"]:
        raise ValueError(f"map version {info['version']} arrived corrupted (SHA-256 mismatch)")
    return FetchedMap(info["version"], pgm, info["metadata"], info["created_at"], info["robot_id"])
