"""Alerts the operators acknowledge, derived from what the store holds: a hazard announced, a
hazard no warden claimed in time, a robot's battery low, a robot stale, a site's uplink near its
bound, dead letters growing, a robot disconnected from the broker.

Each rule is the one the rest of fleetbus uses: the team view's staleness
(:func:`~fleetbus.workers.team.team_member`), the battery watch's threshold
(:func:`~fleetbus.workers.telemetry.battery_low`), the sites' near-full classes
(:func:`~fleetbus.workers.site_status.near_full`), the dead-letter queue's depth
(:func:`~fleetbus.broker.dead_letter_queue.dead_letters_waiting`). A check (:meth:`Alerts.check`)
raises an alert for each condition that holds and has none open, and ends the open alerts whose
condition no longer holds: a robot that stays stale is one alert, however often it is checked, and
a robot that comes back and goes stale again is a second. The API process checks every
``FLEETBUS_ALERTS_CHECK_S`` (:meth:`Alerts.keep_checking`); ``fleetbus alerts`` checks before it
lists. Acknowledging records who and when, once.
"""

from __future__ import annotations

import asyncio
import logging
import re
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from enum import Enum

from fleetbus.api.services.errors import Conflict, Forbidden, NotFound
from fleetbus.broker.policies import SITE_DOWNLINK_PATTERN
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, EventType
from fleetbus.settings import Settings
from fleetbus.workers.overflow import BOUND as OVERFLOW
from fleetbus.workers.site_status import near_full
from fleetbus.workers.store import Repositories
from fleetbus.workers.store.alerts import Alert, AlertStore, NewAlert
from fleetbus.workers.store.base import EventStore
from fleetbus.workers.store.hazards import HazardRegistry, HazardState
from fleetbus.workers.store.housekeeping import Housekeeping
from fleetbus.workers.store.sites import SiteRegistry
from fleetbus.workers.store.team import TeamStore
from fleetbus.workers.team import team_members
from fleetbus.workers.telemetry import battery_low, battery_of

log = logging.getLogger("fleetbus.api.alerts")

#: Who acknowledges alerts: the roles that watch the team (the API, the console and the command line
#: all ask this).
ACKNOWLEDGERS = frozenset({UserRole.ADMIN, UserRole.SUPERVISOR, UserRole.OPERATOR})


class AlertKind(str, Enum):
    HAZARD_ANNOUNCED = "hazard-announced"
    HAZARD_UNCLAIMED = "hazard-unclaimed"
    BATTERY_LOW = "battery-low"
    ROBOT_STALE = "robot-stale"
    UPLINK_NEAR_FULL = "uplink-near-full"
    DEAD_LETTERS = "dead-letters-growing"
    ROBOT_DISCONNECTED = "robot-disconnected"
    DOWNLINK_DROPPED = "downlink-dropped"


#: What each kind means, as the console and ``fleetbus alerts`` say it.
MEANING = {
    AlertKind.HAZARD_ANNOUNCED: "a hazard was announced to the wardens",
    AlertKind.HAZARD_UNCLAIMED: "an announced hazard has no warden's claim after "
    "FLEETBUS_ALERTS_UNCLAIMED_AFTER_S",
    AlertKind.BATTERY_LOW: "a robot's newest status reports its battery below FLEETBUS_BATTERY_LOW_PERCENT",
    AlertKind.ROBOT_STALE: "no event from a robot for FLEETBUS_STALE_AFTER_S (or never)",
    AlertKind.UPLINK_NEAR_FULL: "a site's uplink holds FLEETBUS_UPLINK_ALERT_AT of a class's bound or more",
    AlertKind.DEAD_LETTERS: "the dead-letter queue holds letters, more than when its last alert was "
    "acknowledged",
    AlertKind.ROBOT_DISCONNECTED: "a robot that had a broker connection has had none for "
    "FLEETBUS_ALERTS_DISCONNECTED_S",
    AlertKind.DOWNLINK_DROPPED: "a site's downlink queue at central (accounts, removals, missions) was "
    "full (FLEETBUS_SITE_DOWNLINK_MAX) and dropped its oldest, more than when its last alert was "
    "acknowledged",
}
#: Kinds whose condition may grow after an acknowledgement: grown, it is a new occurrence.
GROWING = frozenset({AlertKind.DEAD_LETTERS.value, AlertKind.DOWNLINK_DROPPED.value})


def downlink_site(subject: str) -> str | None:
    """The site whose downlink queue at central an overflow count is of (``base1.downlink
    maxlen``: ``base1``); None for any other count. The queue as the bound's policy matches it."""
    queue, _, reason = subject.rpartition(" ")
    if reason != "maxlen" or not re.match(SITE_DOWNLINK_PATTERN, queue):
        return None
    return queue.removesuffix(".downlink")


DeadLetterCount = Callable[[], Awaitable[int]]
#: The open connections on the service's virtual host, by broker user (one management API call).
ConnectionCount = Callable[[], Awaitable[Mapping[str, int]]]
#: Takes the sites' reports waiting in central's broker into the store (how many).
ReportCollector = Callable[[], Awaitable[int]]


#: The kinds a hazards-only check looks at.
HAZARD_KINDS = frozenset({AlertKind.HAZARD_ANNOUNCED.value, AlertKind.HAZARD_UNCLAIMED.value})


@dataclass(frozen=True)
class Thresholds:
    unclaimed_after: timedelta
    battery_low_percent: float
    stale_after: timedelta
    uplink_alert_at: float
    disconnected_after: timedelta = timedelta(seconds=10)

    @classmethod
    def of(cls, settings: Settings) -> Thresholds:
        return cls(
            timedelta(seconds=settings.alerts_unclaimed_after_s),
            settings.battery_low_percent,
            timedelta(seconds=settings.stale_after_s),
            settings.uplink_alert_at,
            timedelta(seconds=settings.alerts_disconnected_s),
        )


@dataclass(frozen=True)
class AlertList:
    unacknowledged: list[Alert]
    """Every alert not acknowledged yet, oldest first."""
    acknowledged: list[Alert]
    """The last acknowledged, the last first (none unless asked for)."""


def _clock(moment: datetime) -> str:
    return moment.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def acknowledged_text(alert: Alert) -> str:
    """What an acknowledgement did, as the console and the command line say it."""
    at = _clock(alert.acknowledged_at) if alert.acknowledged_at else "?"
    return f"alert {alert.id} ({alert.kind}, {alert.subject}) acknowledged by {alert.acknowledged_by} at {at}"


class Alerts:
    def __init__(
        self,
        alerts: AlertStore,
        team: TeamStore,
        hazards: HazardRegistry,
        events: EventStore,
        sites: SiteRegistry,
        thresholds: Thresholds,
        dead_letters: DeadLetterCount | None = None,
        shown: int = 50,
        connections: ConnectionCount | None = None,
        collect_reports: ReportCollector | None = None,
        housekeeping: Housekeeping | None = None,
    ) -> None:
        self._alerts = alerts
        self._team = team
        self._hazards = hazards
        self._events = events
        self._sites = sites
        self.thresholds = thresholds
        self._dead_letters = dead_letters
        self.shown = shown
        """How many acknowledged alerts :meth:`listing` gives."""
        self._connections = connections
        self._collect_reports = collect_reports
        """Without it the stored reports are read as they are (someone else takes them in)."""
        self._housekeeping = housekeeping
        """The bounds' counts: what the sites' full downlink queues dropped (None: not looked at)."""
        self._connected_at: dict[str, datetime] | None = None
        """When each robot was last seen with a broker connection (kept by this process: a robot
        never seen connected raises no alert); None until the first look, which begins it from the
        open alerts an earlier process raised."""
        self._lock = asyncio.Lock()

    async def conditions(self, now: datetime, hazards_only: bool = False) -> tuple[list[NewAlert], set[str]]:
        """Every condition that holds at ``now``; and the kinds that could not be looked at (their
        open alerts are left as they are). ``hazards_only``: the hazards' conditions, every other
        kind left as it is."""
        if hazards_only:
            return await self._hazard_conditions(now), {kind.value for kind in AlertKind} - HAZARD_KINDS
        found = [*await self._hazard_conditions(now), *await self._robot_conditions(now)]
        unknown: set[str] = set()
        uplinks = await self._uplink_conditions()
        if uplinks is None:
            unknown.add(AlertKind.UPLINK_NEAR_FULL.value)
        else:
            found += uplinks
        if self._dead_letters is not None:
            try:
                waiting = await self._dead_letters()
            except Exception as error:  # the broker is away: the open alert stays as it was
                log.warning("alerts: the dead letters could not be counted: %s", error)
                unknown.add(AlertKind.DEAD_LETTERS.value)
            else:
                if waiting:
                    letters = f"{waiting:,} dead letter{'' if waiting == 1 else 's'}"
                    detail = f"{letters} waiting (`fleetbus dlq` lists them)"
                    kind = AlertKind.DEAD_LETTERS.value
                    found.append(NewAlert(kind, f"queue {DEAD_LETTER_QUEUE}", now, detail, waiting))
        else:
            unknown.add(AlertKind.DEAD_LETTERS.value)
        if self._housekeeping is None:
            unknown.add(AlertKind.DOWNLINK_DROPPED.value)
        else:
            found += await self._downlink_conditions()
        disconnected = await self._disconnected_conditions(now)
        if disconnected is None:
            unknown.add(AlertKind.ROBOT_DISCONNECTED.value)
        else:
            found += disconnected
        return found, unknown

    async def _disconnected_conditions(self, now: datetime) -> list[NewAlert] | None:
        """The robots that had a connection and have had none for the threshold; None when the
        management API could not be asked (nothing raised, nothing ended)."""
        if self._connections is None:
            return None
        try:
            open_ = await self._connections()
        except Exception as error:  # the management API is away: the open alerts stay as they were
            log.warning("alerts: the broker's connections could not be listed: %s", error)
            return None
        after = self.thresholds.disconnected_after
        names = {robot.name for robot in await self._team.robots()}
        if self._connected_at is None:  # the first look: a robot still away keeps its open alert
            self._connected_at = {
                alert.subject.removeprefix("robot "): alert.since
                for alert in await self._alerts.open_alerts()
                if alert.kind == AlertKind.ROBOT_DISCONNECTED.value
            }
        connected_at = {name: at for name, at in self._connected_at.items() if name in names}
        self._connected_at = connected_at
        found = []
        for name in sorted(names):
            if open_.get(name, 0) > 0:
                connected_at[name] = now
                continue
            last = connected_at.get(name)
            if last is not None and now - last >= after:
                limit = after.total_seconds()
                detail = f"no broker connection since {_clock(last)} (alert after {limit:g} s)"
                found.append(NewAlert(AlertKind.ROBOT_DISCONNECTED.value, f"robot {name}", last, detail))
        return found

    async def _hazard_conditions(self, now: datetime) -> list[NewAlert]:
        counts = await self._hazards.hazard_counts()
        waiting = counts.get(HazardState.ANNOUNCED, 0)
        if not waiting:
            return []
        after = self.thresholds.unclaimed_after
        found = []
        for hazard in await self._hazards.recent_hazards(waiting, state=HazardState.ANNOUNCED):
            subject = f"hazard {hazard.mission_id}/{hazard.hazard_id}"
            since = hazard.announced_at or hazard.received_at
            what = str(hazard.event.get("body", {}).get("description", "")) or "(no description)"
            detected = f"{what} (detected by {hazard.robot_id})"
            found.append(NewAlert(AlertKind.HAZARD_ANNOUNCED.value, subject, since, detected))
            if now - since >= after:
                detail = f"{what}: no warden claimed it in {after.total_seconds():g} s"
                found.append(NewAlert(AlertKind.HAZARD_UNCLAIMED.value, subject, since + after, detail))
        return found

    async def _robot_conditions(self, now: datetime) -> list[NewAlert]:
        robots = await self._team.robots()
        if not robots:
            return []
        members = await team_members(robots, self._events, now, self.thresholds.stale_after)
        statuses = await self._events.newest_events([robot.name for robot in robots], EventType.STATUS.value)
        limit = self.thresholds.battery_low_percent
        found = []
        for member in members:
            name = member.robot.name
            if member.stale:
                seen = member.last_seen
                silent = f"silent since {_clock(seen)}" if seen else "never heard from"
                detail = f"{silent} (stale after {self.thresholds.stale_after.total_seconds():g} s)"
                found.append(NewAlert(AlertKind.ROBOT_STALE.value, f"robot {name}", seen or now, detail))
            status = statuses.get(name)
            percent = battery_of(status.body) if status else None
            if status is not None and percent is not None and battery_low(percent, limit):
                detail = f"battery {percent:.0f} % (low below {limit:g} %)"
                kind = AlertKind.BATTERY_LOW.value
                found.append(NewAlert(kind, f"robot {name}", status.sent_at, detail, percent))
        return found

    async def _uplink_conditions(self) -> list[NewAlert] | None:
        """The sites whose newest report says an uplink class is near full; None when the reports
        waiting in the broker could not be taken in (the stored ones may be old: nothing raised,
        nothing ended)."""
        if self._collect_reports is not None:
            try:
                await self._collect_reports()
            except Exception as error:  # the broker is away: the open alerts stay as they were
                log.warning("alerts: the sites' reports could not be taken in: %s", error)
                return None
        found = []
        for site, report in sorted((await self._sites.reports()).items()):
            full = near_full(report, self.thresholds.uplink_alert_at)
            if full:
                share = max(depth.share for depth in (report.classes or {}).values())
                detail = "uplink " + "; ".join(full)
                kind = AlertKind.UPLINK_NEAR_FULL.value
                found.append(NewAlert(kind, f"site {site}", report.at, detail, share))
        return found

    async def _downlink_conditions(self) -> list[NewAlert]:
        """The sites whose downlink queue at central dropped accounts, removals or missions."""
        assert self._housekeeping is not None
        found = []
        for count in await self._housekeeping.bound_counts():
            site = downlink_site(count.subject) if count.bound == OVERFLOW else None
            if site is None:
                continue
            detail = (
                f"{count.count:,} accounts, removals or missions dropped from {site}.downlink, full while "
                f"the site was away (last {_clock(count.last_at)}): `fleetbus sites sync {site}` sends "
                "them again"
            )
            kind = AlertKind.DOWNLINK_DROPPED.value
            found.append(NewAlert(kind, f"site {site}", count.first_at, detail, count.count))
        return found

    async def check(self, now: datetime | None = None, hazards_only: bool = False) -> list[Alert]:
        """Raise an alert for each condition that holds without one open, end those whose condition
        ended; the alerts raised. ``hazards_only``: only the hazards' alerts (a cheap look)."""
        now = now or datetime.now(timezone.utc)
        async with self._lock:
            current, unknown = await self.conditions(now, hazards_only)
            by_slot = {condition.slot: condition for condition in current}
            held: set[str] = set()
            for alert in await self._alerts.open_alerts():
                condition = by_slot.get(alert.slot)
                if condition is None:
                    if alert.kind not in unknown:
                        await self._alerts.end_alert(alert.id, now)
                    continue
                acknowledged = alert.acknowledged_at is not None
                grown = alert.kind in GROWING and acknowledged and condition.level > alert.level
                if grown:  # more since it was acknowledged: a new occurrence
                    await self._alerts.end_alert(alert.id, now)
                    continue
                held.add(alert.slot)
                if (condition.detail, condition.level) != (alert.detail, alert.level):
                    await self._alerts.update_alert(alert.id, condition.detail, condition.level)
            raised = await self._alerts.raise_alerts([c for c in current if c.slot not in held], now)
        for alert in raised:
            log.info("alert %d raised: %s %s: %s", alert.id, alert.kind, alert.subject, alert.detail)
        return raised

    async def keep_checking(self, every: float, hazards_every: float | None = None) -> None:
        """:meth:`check` every ``every`` seconds until cancelled, and the hazards' alerts alone every
        ``hazards_every`` between (one count and the announced hazards: an operator learns of a
        hazard within that, while the team's and the broker's looks stay rarer); a failure is logged
        and retried."""
        loop = asyncio.get_running_loop()
        step = min(every, hazards_every or every)
        next_full = loop.time()
        while True:
            full = loop.time() >= next_full
            try:
                await self.check(hazards_only=not full)
            except Exception:  # the store is away: the next check tries again
                log.exception("alerts: the check failed; trying again in %g s", step)
            if full:
                next_full = loop.time() + every
            await asyncio.sleep(step)

    async def listing(self, acknowledged: bool = False) -> AlertList:
        """The alerts to acknowledge; with ``acknowledged``, also the last acknowledged."""
        shown = await self._alerts.acknowledged(self.shown) if acknowledged else []
        return AlertList(await self._alerts.unacknowledged(), shown)

    async def acknowledge(self, alert_id: int, by: str, role: UserRole) -> Alert:
        """``by`` (of ``role``) acknowledges the alert: recorded with the time, in UTC, once."""
        if role not in ACKNOWLEDGERS:
            allowed = ", ".join(sorted(r.value for r in ACKNOWLEDGERS))
            raise Forbidden(f"role {role.value} may not acknowledge alerts (roles that may: {allowed})")
        if await self._alerts.acknowledge(alert_id, by, datetime.now(timezone.utc)):
            alert = await self._alerts.get_alert(alert_id)
            if alert is not None:
                log.info("alert %d acknowledged by %s", alert_id, by)
                return alert
        alert = await self._alerts.get_alert(alert_id)
        if alert is None:
            raise NotFound(f"no alert {alert_id}")
        when = _clock(alert.acknowledged_at) if alert.acknowledged_at else "?"
        raise Conflict(f"alert {alert_id} was acknowledged already, by {alert.acknowledged_by} at {when}")


def alerts_for(
    settings: Settings,
    repositories: Repositories,
    dead_letters: DeadLetterCount | None,
    connections: ConnectionCount | None = None,
    collect_reports: ReportCollector | None = None,
) -> Alerts:
    """The alerts over the repositories, with the settings' thresholds; ``dead_letters`` counts the
    dead-letter queue, ``connections`` the broker's connections by user (None: not looked at)."""
    return Alerts(
        repositories.alerts,
        repositories.hazards,
        repositories.hazards,
        repositories.events,
        repositories.sites,
        Thresholds.of(settings),
        dead_letters,
        settings.alerts_acknowledged_shown,
        connections,
        collect_reports,
        repositories.housekeeping,
    )
