"""Alerts the operators acknowledge: each occurrence of a condition (a hazard no warden claimed, a
robot gone stale...) kept once, numbered, with who acknowledged it and when.

A condition is one ``kind`` of one ``subject`` (a robot, a hazard, a site); while it holds it has at
most one open alert, whose ``slot`` (``kind:subject``) a unique index keeps to one however many
processes raise it at once. Ended (the condition no longer holds), the alert gives its slot up, so
the next occurrence is a new alert; acknowledged or not, it stays listed for the record, until the
workers' pruning removes it once it has been acknowledged longer than ``FLEETBUS_ALERTS_KEEP_DAYS``.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone

from fleetbus.workers.store.port import REAL, SERIAL, TEXT, TIME, Database, Doc, Index, Range, Schema

EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


@dataclass(frozen=True)
class NewAlert:
    """A condition that holds now, to be raised unless it already has an open alert."""

    kind: str
    subject: str
    since: datetime
    """When the condition began, as the stored state says (else when it was first seen)."""
    detail: str
    level: float = 0.0
    """How much of it there is (dead letters waiting, a battery's percent), where that matters."""

    @property
    def slot(self) -> str:
        return f"{self.kind}:{self.subject}"


@dataclass(frozen=True)
class Alert:
    id: int
    kind: str
    subject: str
    since: datetime
    raised_at: datetime
    detail: str
    level: float
    ended_at: datetime | None = None
    """When the condition was last seen no longer to hold; None while it holds."""
    acknowledged_by: str | None = None
    acknowledged_at: datetime | None = None

    @property
    def open(self) -> bool:
        return self.ended_at is None

    @property
    def slot(self) -> str:
        return f"{self.kind}:{self.subject}"


class AlertStore(abc.ABC):
    @abc.abstractmethod
    async def raise_alerts(self, new: Sequence[NewAlert], at: datetime) -> list[Alert]:
        """Keep each of ``new`` as an alert raised ``at``, unless its condition has an open alert
        already (raised by anyone); the alerts raised."""

    @abc.abstractmethod
    async def open_alerts(self) -> list[Alert]:
        """The alerts whose condition still held when last looked at, oldest first."""

    @abc.abstractmethod
    async def end_alert(self, alert_id: int, at: datetime) -> bool:
        """Its condition no longer holds (at ``at``): the alert ends and gives its slot up; False
        when it had ended already."""

    @abc.abstractmethod
    async def update_alert(self, alert_id: int, detail: str, level: float) -> None:
        """An open alert's condition, as it stands now."""

    @abc.abstractmethod
    async def get_alert(self, alert_id: int) -> Alert | None: ...

    @abc.abstractmethod
    async def unacknowledged(self) -> list[Alert]:
        """Every alert not acknowledged yet, oldest first."""

    @abc.abstractmethod
    async def acknowledged(self, limit: int) -> list[Alert]:
        """The ``limit`` alerts acknowledged last, the last first."""

    @abc.abstractmethod
    async def acknowledge(self, alert_id: int, by: str, at: datetime) -> bool:
        """Record that ``by`` acknowledged the alert ``at``; False when it is not there or was
        acknowledged before (by anyone: the first acknowledgement stays)."""

    @abc.abstractmethod
    async def prune_alerts(self, acknowledged_before: datetime, limit: int) -> int:
        """Delete up to ``limit`` alerts acknowledged before ``acknowledged_before`` whose condition
        ended, the earliest acknowledged first; how many went. An open alert stays, acknowledged
        or not: it holds its condition's slot, and without it the condition would be raised again."""


ALERTS = Schema(
    "alerts",
    {
        "kind": TEXT,
        "subject": TEXT,
        "since": TIME,
        "raised_at": TIME,
        "detail": TEXT,
        "level": REAL,
        "slot": TEXT,
        "ended_at": TIME.maybe,
        "acknowledged_by": TEXT.maybe,
        "acknowledged_at": TIME.maybe,
    },
    serial=True,
    indexes=(Index("slot", unique=True), Index("ended_at", SERIAL), Index("acknowledged_at", SERIAL)),
)
"""``slot`` is ``kind:subject`` while the alert is open, ``ended:<id>`` after (unique either way)."""


def _alert(doc: Doc) -> Alert:
    fields = dict(doc)
    fields.pop("slot")
    return Alert(id=fields.pop(SERIAL), **fields)


class Alerts(AlertStore):
    """Every step is one atomic write (an insert refused by the slot's unique index, an update
    conditional on what it changes), so two processes checking at once raise an occurrence once
    and acknowledge it once."""

    def __init__(self, database: Database) -> None:
        self._alerts = database.collection(ALERTS)

    async def raise_alerts(self, new: Sequence[NewAlert], at: datetime) -> list[Alert]:
        if not new:
            return []
        docs = [
            {
                "kind": n.kind,
                "subject": n.subject,
                "since": n.since,
                "raised_at": at,
                "detail": n.detail,
                "level": float(n.level),
                "slot": n.slot,
                "ended_at": None,
                "acknowledged_by": None,
                "acknowledged_at": None,
            }
            for n in new
        ]
        inserted = await self._alerts.insert(docs)
        slots = [n.slot for n, done in zip(new, inserted, strict=True) if done]
        if not slots:
            return []
        return [alert for alert in await self.open_alerts() if alert.slot in slots]

    async def open_alerts(self) -> list[Alert]:
        return [_alert(doc) for doc in await self._alerts.find({"ended_at": None}, order=[SERIAL])]

    async def end_alert(self, alert_id: int, at: datetime) -> bool:
        where = {SERIAL: alert_id, "ended_at": None}
        return await self._alerts.update(where, {"ended_at": at, "slot": f"ended:{alert_id}"}) == 1

    async def update_alert(self, alert_id: int, detail: str, level: float) -> None:
        await self._alerts.update({SERIAL: alert_id}, {"detail": detail, "level": float(level)})

    async def get_alert(self, alert_id: int) -> Alert | None:
        doc = await self._alerts.get(alert_id)
        return _alert(doc) if doc else None

    async def unacknowledged(self) -> list[Alert]:
        return [_alert(doc) for doc in await self._alerts.find({"acknowledged_at": None}, order=[SERIAL])]

    async def acknowledged(self, limit: int) -> list[Alert]:
        found = await self._alerts.find(
            {"acknowledged_at": Range(ge=EPOCH)},
            order=["-acknowledged_at", f"-{SERIAL}"],
            limit=limit,
        )
        return [_alert(doc) for doc in found]

    async def acknowledge(self, alert_id: int, by: str, at: datetime) -> bool:
        where = {SERIAL: alert_id, "acknowledged_at": None}
        return await self._alerts.update(where, {"acknowledged_by": by, "acknowledged_at": at}) == 1

    async def prune_alerts(self, acknowledged_before: datetime, limit: int) -> int:
        where = {"acknowledged_at": Range(lt=acknowledged_before), "ended_at": Range(ge=EPOCH)}
        return await self._alerts.delete(where, order=["acknowledged_at", SERIAL], limit=limit)
