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
