"""What the server knows of each robot's sequence numbers: gaps, and duplicates it was sent.

Every start of a robot's client numbers its events 0, 1, 2, ... within an epoch of its own
(:mod:`fleetbus.schemas.envelope`). The ledger keeps, per robot and epoch, the highest number stored (the
high-water mark) and the ranges below it that the store does not hold (gaps). A gap opens when a
number arrives beyond the next one expected and closes, piece by piece, when the missing events
arrive later. Observing a number twice changes nothing, so a redelivered batch can be observed
again safely; the result does not depend on the order of observation.

A duplicate is an event the store already held under the same (robot, epoch, seq) and message
id: a robot that resent after a lost confirm, or a redelivery after a worker crash
(``redelivered``).
"""

from __future__ import annotations

import abc
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import datetime
from typing import NamedTuple

from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.port import (
    BOOL,
    INTEGER,
    JSON,
    SERIAL,
    TEXT,
    TIME,
    Database,
    Doc,
    Index,
    Range,
    Schema,
)


class RobotEpoch(NamedTuple):
    """One numbering: a robot, and the epoch of the client start that numbered the events."""

    robot_id: str
    epoch: str


@dataclass(frozen=True)
class Gap:
    robot_id: str
    epoch: str
    first: int
    last: int
    detected_at: datetime

    @property
    def size(self) -> int:
        return self.last - self.first + 1


@dataclass(frozen=True)
class Duplicate:
    robot_id: str
    epoch: str
    seq: int
    message_id: str
    seen_at: datetime
    redelivered: bool
    """The broker redelivered it (a worker died before acking), rather than the robot resending it."""


@dataclass(frozen=True)
class LedgerChange:
    high_water: int
    gaps: list[Gap]
    """The gaps that replace the ``touched`` ones."""
    touched: list[Gap]


def apply_seqs(
    numbering: RobotEpoch, high_water: int | None, touched: Sequence[Gap], seqs: Iterable[int], at: datetime
) -> LedgerChange:
    """One numbering's ledger after observing ``seqs``, given the gaps that contain any of them
    (``touched``)."""
    hw = -1 if high_water is None else high_water
    gaps = sorted(touched, key=lambda gap: gap.first)
    for seq in sorted(set(seqs)):
        if seq > hw:
            if seq > hw + 1:
                gaps.append(Gap(*numbering, hw + 1, seq - 1, at))
            hw = seq
            continue
        for index, gap in enumerate(gaps):
            if gap.first <= seq <= gap.last:
                pieces = []
                if gap.first < seq:
                    pieces.append(replace(gap, last=seq - 1))
                if seq < gap.last:
                    pieces.append(replace(gap, first=seq + 1))
                gaps[index : index + 1] = pieces
                break
    return LedgerChange(hw, gaps, list(touched))


def seen_numbers(high_water: int | None, gaps: Iterable[Gap], seqs: Iterable[int]) -> set[int]:
    """Of ``seqs``, the numbers the ledger has observed: at or below the high-water mark and in no
    gap. An event pruned from the log stays observed here, which is what keeps a late resend of it
    from being stored again."""
    if high_water is None:
        return set()
    holes = list(gaps)
    return {
        seq for seq in seqs if seq <= high_water and not any(gap.first <= seq <= gap.last for gap in holes)
    }


class SequenceLedger(abc.ABC):
    @abc.abstractmethod
    async def observe_sequences(self, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
        """Record that these numbers' events are stored; open and close gaps accordingly (idempotent)."""

    @abc.abstractmethod
    async def record_duplicates(self, duplicates: Sequence[Duplicate]) -> None: ...

    @abc.abstractmethod
    async def gaps(self, robot_id: str | None = None) -> list[Gap]:
        """Open gaps, by robot, epoch, then first missing number."""

    @abc.abstractmethod
    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        """Duplicates seen, newest first."""

    @abc.abstractmethod
    async def high_water(self, robot_id: str, epoch: str) -> int | None:
        """The highest sequence number stored for the robot in ``epoch``, None before its first event."""


SEQUENCES = Schema(
    "robot_sequences",
    {
        "robot_id": TEXT,
        "epoch": TEXT,
        "high_water": INTEGER,
        "gaps": JSON,
        "version": INTEGER,
        "seen_at": TIME.maybe,
        "open": INTEGER.maybe,
    },
    key=("robot_id", "epoch"),
    indexes=(Index("robot_id"), Index("open"), Index("seen_at")),
)
"""One document per numbering: its high-water mark and its open gaps (``[first, last, detected
at]``), written back only if its version is still the one read, so two workers observing one
numbering at once lose nothing, and a worker that dies mid-way leaves it as it was. (A robot
with hundreds of thousands of open gaps would reach MongoDB's 16 MB document limit.) ``seen_at``:
when its numbers were last observed (the pruning of numberings no longer in use goes by it);
``open``: how many gaps it has (the gaps are read from those that have some). Both are None in a
document written before they were kept, until it is observed again."""
DUPLICATES = Schema(
    "duplicates",
    {
        "robot_id": TEXT,
        "epoch": TEXT,
        "seq": INTEGER,
        "message_id": TEXT,
        "seen_at": TIME,
        "redelivered": BOOL,
    },
    serial=True,
    indexes=(Index("robot_id", "seen_at"), Index("seen_at")),
)


def _gaps(doc: Doc) -> list[Gap]:
    return [
        Gap(doc["robot_id"], doc["epoch"], first, last, from_micros(at)) for first, last, at in doc["gaps"]
    ]


class Ledger(SequenceLedger):
    def __init__(self, database: Database) -> None:
        self._database = database
        self._sequences = database.collection(SEQUENCES)
        self._duplicates = database.collection(DUPLICATES)

    async def high_water(self, robot_id: str, epoch: str) -> int | None:
        doc = await self._sequences.get(robot_id, epoch)
        return doc["high_water"] if doc else None

    async def observed(self, wanted: Mapping[RobotEpoch, Sequence[int]]) -> set[tuple[str, str, int]]:
        """The (robot, epoch, seq) keys of ``wanted`` the ledger has seen."""
        keys: set[tuple[str, str, int]] = set()
        numberings = list(wanted)
        for numbering, doc in zip(numberings, await self._sequences.get_many(numberings), strict=True):
            if doc is not None:
                seen = seen_numbers(doc["high_water"], _gaps(doc), wanted[numbering])
                keys.update((*numbering, seq) for seq in seen)
        return keys

    async def observe_sequences(self, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
        work = {RobotEpoch(*numbering): list(seqs) for numbering, seqs in seen.items() if seqs}
        if work:
            await self._database.transaction(lambda: self.observe(work, at))

    async def observe(self, seen: Mapping[RobotEpoch, Sequence[int]], at: datetime) -> None:
        """:meth:`observe_sequences`, within the caller's unit of work."""
        for numbering, seqs in seen.items():
            while not await self._observe(numbering, seqs, at):
                pass  # another observer changed this numbering's ledger meanwhile: again, from it

    async def _observe(self, numbering: RobotEpoch, seqs: Sequence[int], at: datetime) -> bool:
        """One attempt; False if another observer wrote the numbering's document first."""
        doc = await self._sequences.get(*numbering)
        high_water = doc["high_water"] if doc else None
        gaps = _gaps(doc) if doc else []
        low, high = min(seqs), max(seqs)
        touched = [
            g for g in gaps if high_water is not None and g.last >= low and g.first <= min(high, high_water)
        ]
        change = apply_seqs(numbering, high_water, touched, seqs, at)
        kept = [g for g in gaps if g not in touched]
        now_open = sorted([*kept, *change.gaps], key=lambda g: g.first)
        after = {
            "high_water": change.high_water,
            "gaps": [[g.first, g.last, to_micros(g.detected_at)] for g in now_open],
            "seen_at": at,
            "open": len(now_open),
        }
        if doc is None:
            return (await self._sequences.insert([{**numbering._asdict(), **after, "version": 0}]))[0]
        where = {**numbering._asdict(), "version": doc["version"]}
        return await self._sequences.update(where, after, add={"version": 1}) == 1

    async def record_duplicates(self, duplicates: Sequence[Duplicate]) -> None:
        await self._duplicates.insert([duplicate.__dict__ for duplicate in duplicates])

    async def gaps(self, robot_id: str | None = None) -> list[Gap]:
        robot = {"robot_id": robot_id} if robot_id else {}
        # the numberings with gaps, and those not observed since their count was kept
        found = [
            *await self._sequences.find({**robot, "open": Range(gt=0)}),
            *await self._sequences.find({**robot, "open": None}),
        ]
        return sorted(
            (gap for doc in found for gap in _gaps(doc)), key=lambda g: (g.robot_id, g.epoch, g.first)
        )

    async def duplicates(self, robot_id: str | None = None, limit: int | None = None) -> list[Duplicate]:
        found = await self._duplicates.find(
            {"robot_id": robot_id} if robot_id else {},
            order=["-seen_at", "robot_id", "-epoch", "-seq"],
            limit=limit,
            fields=[name for name in DUPLICATES.fields if name != SERIAL],
        )
        return [Duplicate(**doc) for doc in found]
