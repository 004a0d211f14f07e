"""The large byte arrays of live ROS messages, put together in the recording's blob store.

The bridge sends each byte array over :data:`~fleetbus.schemas.ros.BLOB_FROM` (an image's pixels)
as ``ros_chunk`` events, in order, before the ``ros`` event that names it as ``{"_blob": sha256,
"length": n}``. The recorder, for each batch, in the order of delivery:

- keeps each chunk's bytes in the blob store under :func:`piece_name` (its blob and index), and
  records the chunk event without them (their size instead);
- makes each blob a ``ros`` record names from its pieces, checked against its length and SHA-256,
  and keeps it under its SHA-256; a blob whose pieces are not all there, and that the store does
  not hold already, is described instead (``{"_truncated": true, "length", "sha256", "missing"}``)
  and the record's problem says so: a record never names a blob the store does not hold;
- once the records are written, forgets the pieces of the blobs it made.

Each piece is noted in the recording's bookkeeping before it is written, and forgotten with it:
the pieces of a message whose record never came (its bridge killed mid-message, a resent piece
of a message recorded already) are swept once they are older than ``FLEETBUS_ROS_PIECES_TTL``
(:meth:`RosBlobs.sweep`), and counted.

Each step may be done again (a redelivery after a crash) with the same outcome: a piece or a blob
kept already is not written twice, and a blob made already is found whole when its pieces are gone.
"""

from __future__ import annotations

import base64
import hashlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.bodies import chunk_count
from fleetbus.schemas.ros import BLOB_KEY, ROS_TYPE, TRUNCATED_KEY
from fleetbus.schemas.routing import EventType
from fleetbus.workers.store.recordings import RecordedMessage, RecordingStore

log = logging.getLogger("fleetbus.recorder")
CHUNK_TYPE = EventType.ROS_CHUNK.value
Retrying = Callable[[Callable[[], Awaitable[Any]]], Awaitable[Any]]
#: Pieces a sweep forgets in one step.
SWEEP_BATCH = 500


def piece_name(blob: str, index: int) -> str:
    """The blob store's name of the ``index``-th piece of ``blob`` (a SHA-256, as every name there)."""
    return hashlib.sha256(f"{CHUNK_TYPE}\0{blob}\0{index}".encode()).hexdigest()


@dataclass
class BlobStats:
    made: int = 0
    """Blobs put together from their pieces."""
    missing: int = 0
    """Blobs a record named whose pieces did not all arrive: described, not kept."""
    swept: int = 0
    """Pieces removed because no record named them in time."""


@dataclass
class RosBlobs:
    store: RecordingStore
    retrying: Retrying
    stats: BlobStats = field(default_factory=BlobStats)

    async def prepare(self, records: list[RecordedMessage]) -> tuple[list[RecordedMessage], list[str]]:
        """``records`` as they are to be written (chunks without their bytes, each ``ros`` record
        naming only blobs the store holds), and the pieces to forget once they are written."""
        prepared: list[RecordedMessage] = []
        done: list[str] = []
        for record in records:
            if record.type == CHUNK_TYPE:
                record = await self._stage(record)
            elif record.type == ROS_TYPE and isinstance(record.document, dict):
                record = await self._make_blobs(record, done)
            prepared.append(record)
        return prepared, done

    async def settle(self, pieces: list[str]) -> None:
        if pieces:
            await self.retrying(lambda: self.store.delete_blobs(pieces))
            await self.retrying(lambda: self.store.bookkeeping.pieces_settled(pieces))

    async def sweep(self, before: datetime) -> dict[str, int]:
        """Remove the pieces noted before ``before`` (no record named them since); how many of
        them the blob store still held, by robot."""
        removed: dict[str, int] = {}
        bookkeeping = self.store.bookkeeping
        while stale := await bookkeeping.pieces_staged_before(before, SWEEP_BATCH):
            by_robot: dict[str, list[str]] = {}
            for name, robot in stale:
                by_robot.setdefault(robot or "(unknown)", []).append(name)
            for robot, names in sorted(by_robot.items()):
                count = await self.store.delete_blobs(names)
                if count:
                    removed[robot] = removed.get(robot, 0) + count
            await bookkeeping.pieces_settled([name for name, _ in stale])
            if len(stale) < SWEEP_BATCH:
                break
        self.stats.swept += sum(removed.values())
        return removed

    async def _stage(self, record: RecordedMessage) -> RecordedMessage:
        envelope = record.document
        body = envelope.get("body") if isinstance(envelope, dict) else None
        if not isinstance(body, dict) or not isinstance(body.get("data"), str):
            return record  # not a chunk (the capture said what is wrong with it)
        try:
            data = base64.b64decode(body["data"], validate=True)
            name = piece_name(str(body["blob"]), int(body["index"]))
        except (ValueError, KeyError, TypeError) as error:
            problem = f"a ros_chunk that cannot be read: {error}"
            return replace(record, problem="; ".join(p for p in (record.problem, problem) if p))
        at = datetime.now(timezone.utc)
        await self.retrying(lambda: self.store.bookkeeping.piece_staged(name, record.robot_id, at))
        await self.retrying(lambda: self.store.put_blob(name, data))
        kept = {**body, "data": None, "size": len(data)}
        return replace(record, document={**envelope, "body": kept})

    async def _make_blobs(self, record: RecordedMessage, done: list[str]) -> RecordedMessage:
        problems: list[str] = []

        async def resolved(value: Any) -> Any:
            if isinstance(value, list):
                return [await resolved(item) for item in value]
            if not isinstance(value, dict):
                return value
            if BLOB_KEY not in value:
                return {key: await resolved(item) for key, item in value.items()}
            digest, length = str(value[BLOB_KEY]), int(value.get("length") or 0)
            problem = await self._make(digest, length, done)
            if problem is None:
                return value
            problems.append(problem)
            return {TRUNCATED_KEY: True, "length": length, "sha256": digest, "missing": problem}

        document = record.document
        fields = await resolved(document.get("fields"))
        if not problems:
            return record
        problem = "; ".join(p for p in (record.problem, *problems) if p)
        return replace(record, document={**document, "fields": fields}, problem=problem)

    async def _make(self, digest: str, length: int, done: list[str]) -> str | None:
        """Put the blob together from its pieces; None when the store holds it, else what is wrong."""
        count = chunk_count(length)
        names = [piece_name(digest, index) for index in range(count)]
        pieces = [await self.retrying(lambda name=name: self.store.get_blob(name)) for name in names]
        if all(piece is not None for piece in pieces):
            data = b"".join(pieces)  # type: ignore[arg-type]
            if len(data) == length and hashlib.sha256(data).hexdigest() == digest:
                await self.retrying(lambda: self.store.put_blob(digest, data))
                done.extend(names)
                self.stats.made += 1
                return None
            wrong = f"its {count} pieces make {len(data)} bytes that do not match its length and SHA-256"
        else:
            absent = sum(piece is None for piece in pieces)
            wrong = f"{absent} of its {count} pieces did not arrive"
        if await self.retrying(lambda: self.store.get_blob(digest)) is not None:
            done.extend(name for name, piece in zip(names, pieces, strict=True) if piece is not None)
            return None  # made already (this is a redelivery)
        self.stats.missing += 1
        said = f"the byte array {digest} ({length} bytes) is not kept: {wrong}"
        log.warning("a ROS message recorded without its data: %s", said)
        return said
