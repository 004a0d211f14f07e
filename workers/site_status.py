"""How each site's link fares, as central sees it and as the site sees it (``fleetbus sites``,
``fleetbus site status``, the console's dashboard)."""

from __future__ import annotations

import contextlib
from collections.abc import Collection
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from fleetbus.broker.management import ManagementAPI, ManagementError, oldest_by_user
from fleetbus.broker.sites import forwarded_robots
from fleetbus.broker.uplink import CLASSES
from fleetbus.schemas.routing import (
    DOWNLINK_MAPS_SHOVEL,
    DOWNLINK_REJECTED_QUEUE,
    DOWNLINK_SHOVEL,
    HAZARD_UPLINK_QUEUE,
    HAZARD_UPLINK_SHOVEL,
    UPLINK_SHOVEL,
)
from fleetbus.schemas.site_reports import SiteReport, UplinkDepth
from fleetbus.workers.store.sites import SiteSummary


@dataclass(frozen=True)
class SiteRow:
    """One site as central sees it."""

    site: str
    robots: tuple[str, ...]
    link_up: bool
    """The site's account has a connection open to central (its uplink shovel's)."""
    since: datetime | None
    """Up: when that connection opened. Down: when central last received an event from the site."""
    forwarded: int
    late: int
    behind_s: float | None
    """Seconds between now and the send time of the newest event central received from the site:
    how far behind central is (while the site is busy), or how long the site has been quiet."""
    waiting: int | None = None
    """Events waiting at the site to be forwarded, as its newest report said (None: no report)."""
    reported_at: datetime | None = None
    """When the site measured its newest report."""
    report_age_s: float | None = None
    """How old that report is: while the link is down it grows, and ``waiting`` is that old."""
    hazard_states_waiting: int | None = None
    """Hazard states made at the site waiting to be forwarded, as its newest report said."""
    near_full: tuple[str, ...] = ()
    """The classes of its uplink at ``FLEETBUS_UPLINK_ALERT_AT`` of their bound or more, as its
    newest report said (described: ``telemetry 85 % of 200,000``): an alert."""

    def as_dict(self) -> dict[str, Any]:
        return {
            **self.__dict__,
            "robots": list(self.robots),
            "near_full": list(self.near_full),
            "since": self.since.isoformat() if self.since else None,
            "reported_at": self.reported_at.isoformat() if self.reported_at else None,
        }


def near_full(report: SiteReport | None, alert_at: float) -> tuple[str, ...]:
    """The classes of a site's uplink the report says are at ``alert_at`` of their bound or more."""
    if report is None or not report.classes:
        return ()
    return tuple(
        f"{name} {depth.share:.0%} of {depth.bound:,}"
        + (" (new ones refused when full)" if depth.overflow == "reject-publish" else " (oldest dropped)")
        for name, depth in report.classes.items()
        if depth.share >= alert_at
    )


def central_view(
    api: ManagementAPI,
    vhost: str,
    summaries: list[SiteSummary],
    now: datetime,
    reports: dict[str, SiteReport] | None = None,
    alert_at: float = 0.8,
) -> list[SiteRow]:
    opened = oldest_by_user(api.list_vhost_connections(vhost))
    rows = []
    for summary in summaries:
        up = summary.site in opened
        report = (reports or {}).get(summary.site)
        rows.append(
            SiteRow(
                summary.site,
                summary.robots,
                up,
                opened[summary.site] if up else summary.last_received_at,
                summary.forwarded,
                summary.late,
                (now - summary.newest_sent_at).total_seconds() if summary.newest_sent_at else None,
                report.waiting if report else None,
                report.at if report else None,
                max(0.0, (now - report.at).total_seconds()) if report else None,
                report.hazard_states_waiting if report else None,
                near_full(report, alert_at),
            )
        )
    return rows


@dataclass(frozen=True)
class ShovelState:
    name: str
    state: str
    """``running``, ``starting`` (connecting, or waiting to connect again), ``terminated``, or
    ``absent`` (no such shovel)."""
    since: str | None
    """When it entered that state, as RabbitMQ tells it (the node's local time)."""
    reason: str | None = None


@dataclass(frozen=True)
class SiteLink:
    """The site's own view: its shovels, and what waits in its uplink."""

    uplink: ShovelState
    """The events class's shovel (``fleetbus-uplink``); the others are in ``classes``."""
    downlink: ShovelState
    waiting: int | None
    """Events in the uplink's classes not yet confirmed by central (ready and in flight)."""
    not_forwarded: list[str]
    """Robots of the site's team whose events are not forwarded (central did not send them)."""
    rejected: int | None = None
    """Downlink messages ``fleetbus site apply`` could not parse (in ``fleetbus.downlink.rejected``)."""
    rejected_bound: int | None = None
    """How many of those the queue keeps (its policy's, set by ``fleetbus site up``); None: unbounded."""
    hazard_uplink: ShovelState | None = None
    """The shovel of the hazards' states."""
    hazard_states_waiting: int | None = None
    """Hazard states in ``fleetbus.hazard-uplink`` not yet confirmed by central."""
    classes: dict[str, UplinkDepth] = field(default_factory=dict)
    """Each class of the uplink: what waits, its bound and overflow (the classes the broker told)."""
    shovels: dict[str, ShovelState] = field(default_factory=dict)
    """Each class's shovel and the maps' downlink."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "classes": {name: depth.model_dump() for name, depth in self.classes.items()},
            "shovels": {name: shovel.__dict__ for name, shovel in self.shovels.items()},
            "uplink": self.uplink.__dict__,
            "downlink": self.downlink.__dict__,
            "hazard_uplink": self.hazard_uplink.__dict__ if self.hazard_uplink else None,
            "waiting": self.waiting,
            "hazard_states_waiting": self.hazard_states_waiting,
            "not_forwarded": self.not_forwarded,
            "rejected": self.rejected,
            "rejected_bound": self.rejected_bound,
        }


def site_view(api: ManagementAPI, vhost: str, team: Collection[str]) -> SiteLink:
    """The site's links, and which of ``team`` (the robots the site's store knows) are not forwarded."""
    found = {shovel.get("name"): shovel for shovel in api.shovel_status(vhost)}

    def state(name: str) -> ShovelState:
        shovel = found.get(name)
        if shovel is None:
            return ShovelState(name, "absent", None)
        reason = shovel.get("reason")
        return ShovelState(
            name, str(shovel.get("state")), shovel.get("timestamp"), str(reason) if reason else None
        )

    def held(queue_name: str) -> int | None:
        """Ready and in flight in ``queue_name``; None when the broker cannot tell."""
        with contextlib.suppress(ManagementError):
            queue = api.get_queue(vhost, queue_name)
            return int(queue.get("messages_ready", 0)) + int(queue.get("messages_unacknowledged", 0))
        return None

    def bound(queue_name: str) -> int | None:
        with contextlib.suppress(ManagementError):
            policy = api.get_queue(vhost, queue_name).get("effective_policy_definition") or {}
            return int(policy["max-length"]) if "max-length" in policy else None
        return None

    not_forwarded = sorted(set(team) - forwarded_robots(api, vhost))
    classes: dict[str, UplinkDepth] = {}
    for uplink in CLASSES:
        waiting, limit = held(uplink.queue), bound(uplink.queue)
        if waiting is not None and limit:
            classes[uplink.name] = UplinkDepth(waiting=waiting, bound=limit, overflow=uplink.overflow)
    counts = [held(uplink.queue) for uplink in CLASSES]
    return SiteLink(
        state(UPLINK_SHOVEL),
        state(DOWNLINK_SHOVEL),
        None if any(n is None for n in counts) else sum(n or 0 for n in counts),
        not_forwarded,
        held(DOWNLINK_REJECTED_QUEUE),
        bound(DOWNLINK_REJECTED_QUEUE),
        state(HAZARD_UPLINK_SHOVEL),
        held(HAZARD_UPLINK_QUEUE),
        classes,
        {name: state(name) for name in (*(u.shovel for u in CLASSES), DOWNLINK_MAPS_SHOVEL)},
    )
