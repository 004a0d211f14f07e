"""Alerts on every adapter: an occurrence raised once however often it is checked, a new one after
its condition ended, acknowledged once (who and when kept exactly); and the checks of the
application layer over the store: a hazard unclaimed, a site's uplink near its bound, dead letters
growing after an acknowledgement."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.api.services.alerts import AlertKind, Alerts, Thresholds
from fleetbus.schemas.envelope import build_event
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.site_reports import SiteReport, UplinkDepth
from fleetbus.workers.store.alerts import NewAlert
from fleetbus.workers.store.repositories import Repositories
from tests import factories

T0 = datetime(2026, 11, 28, 2, 0, 0, 123456, tzinfo=timezone.utc)
SECOND = timedelta(seconds=1)
EPOCH = "20261128T000000000Z-0000beef"


def stale(name: str, since: datetime = T0) -> NewAlert:
    return NewAlert("robot-stale", f"robot {name}", since, "never heard from")


async def test_an_open_condition_is_raised_once_and_again_only_after_it_ended(store: Repositories) -> None:
    alerts = store.alerts
    [first] = await alerts.raise_alerts([stale("explorer1"), stale("explorer1")], T0)
    assert (first.kind, first.subject, first.since) == ("robot-stale", "robot explorer1", T0)
    assert first.raised_at == T0
    assert (first.ended_at, first.acknowledged_by, first.acknowledged_at) == (None, None, None)
    assert await alerts.raise_alerts([stale("explorer1", T0 + SECOND)], T0 + SECOND) == [], "still open"
    [other] = await alerts.raise_alerts([stale("warden1")], T0)
    assert other.id > first.id
    assert [a.id for a in await alerts.open_alerts()] == [first.id, other.id]

    assert await alerts.end_alert(first.id, T0 + 2 * SECOND)
    assert not await alerts.end_alert(first.id, T0 + 3 * SECOND), "ended once"
    [again] = await alerts.raise_alerts([stale("explorer1", T0 + 4 * SECOND)], T0 + 4 * SECOND)
    assert again.id > other.id and again.since == T0 + 4 * SECOND
    ended = await alerts.get_alert(first.id)
    assert ended is not None and ended.ended_at == T0 + 2 * SECOND
    assert [a.id for a in await alerts.open_alerts()] == [other.id, again.id]
    assert [a.id for a in await alerts.unacknowledged()] == [first.id, other.id, again.id]


async def test_an_alert_is_acknowledged_once_and_the_first_acknowledgement_stays(store: Repositories) -> None:
    alerts = store.alerts
    [one, two] = await alerts.raise_alerts([stale("a"), stale("b")], T0)
    assert await alerts.acknowledge(one.id, "oper1", T0 + SECOND)
    assert not await alerts.acknowledge(one.id, "super1", T0 + 2 * SECOND)
    assert not await alerts.acknowledge(999_999, "oper1", T0)
    assert await alerts.acknowledge(two.id, "super1", T0 + 3 * SECOND)
    kept = await alerts.get_alert(one.id)
    assert kept is not None and (kept.acknowledged_by, kept.acknowledged_at) == ("oper1", T0 + SECOND)
    assert [a.id for a in await alerts.acknowledged(10)] == [two.id, one.id], "the last acknowledged first"
    assert [a.id for a in await alerts.acknowledged(1)] == [two.id]
    assert await alerts.unacknowledged() == []

    # pruned: only an alert both acknowledged before the bound and ended (an open one holds its slot)
    assert await alerts.prune_alerts(T0 + 10 * SECOND, 100) == 0, "open alerts stay, acknowledged or not"
    [unseen] = await alerts.raise_alerts([stale("c")], T0)
    for alert in (one, two, unseen):
        assert await alerts.end_alert(alert.id, T0 + 4 * SECOND)
    assert await alerts.prune_alerts(T0 + 2 * SECOND, 100) == 1
    assert await alerts.get_alert(one.id) is None
    assert [a.id for a in await alerts.acknowledged(10)] == [two.id], "acknowledged after the bound: kept"
    assert [a.id for a in await alerts.unacknowledged()] == [unseen.id], "never acknowledged: kept"


class Counter:
    """The dead-letter queue's depth, as a test sets it."""

    def __init__(self) -> None:
        self.waiting = 0

    async def __call__(self) -> int:
        return self.waiting


async def test_the_checks_raise_each_occurrence_once_and_dead_letters_again_when_they_grow(
    store: Repositories,
) -> None:
    dead = Counter()
    thresholds = Thresholds(timedelta(seconds=60), 20.0, timedelta(seconds=60), 0.8)
    alerts = Alerts(store.alerts, store.hazards, store.hazards, store.events, store.sites, thresholds, dead)
    sent = build_event("hazard", "explorer1", EPOCH, 0, factories.hazard(0, "Smoke")).model_dump(mode="json")
    await store.hazards.add_hazard("default", "explorer1", EPOCH, 0, sent, T0, held=False)
    full = UplinkDepth(waiting=90, bound=100, overflow="reject-publish")
    report = SiteReport(
        site="north", at=T0, waiting=90, classes={"hazards": full}, uplink="running", downlink="running"
    )
    await store.sites.put_report(report)

    # the API process's quick look between its full ones: the hazards alone
    [announced] = await alerts.check(T0 + SECOND, hazards_only=True)
    assert (announced.kind, announced.subject) == (AlertKind.HAZARD_ANNOUNCED.value, "hazard default/1")
    assert "Smoke" in announced.detail
    raised = await alerts.check(T0 + SECOND)
    assert [(a.kind, a.subject) for a in raised] == [(AlertKind.UPLINK_NEAR_FULL.value, "site north")]
    unclaimed = await alerts.check(T0 + 61 * SECOND)
    assert [(a.kind, a.since) for a in unclaimed] == [(AlertKind.HAZARD_UNCLAIMED.value, T0 + 60 * SECOND)]
    assert await alerts.check(T0 + 62 * SECOND) == [], "one alert per occurrence, however often checked"

    dead.waiting = 3
    [letters] = await alerts.check(T0 + 63 * SECOND)
    assert (letters.kind, letters.level) == (AlertKind.DEAD_LETTERS.value, 3)
    dead.waiting = 5
    assert await alerts.check(T0 + 64 * SECOND) == [], "growing while not acknowledged: the same alert"
    await alerts.acknowledge(letters.id, "oper1", UserRole.OPERATOR)
    assert await alerts.check(T0 + 65 * SECOND) == [], "as many as when acknowledged"
    dead.waiting = 6
    [grown] = await alerts.check(T0 + 66 * SECOND)
    assert grown.kind == AlertKind.DEAD_LETTERS.value and "6 dead letters" in grown.detail
    first = await store.alerts.get_alert(letters.id)
    assert first is not None and first.ended_at == T0 + 66 * SECOND and first.acknowledged_by == "oper1"
    dead.waiting = 0
    await alerts.check(T0 + 67 * SECOND, hazards_only=True)
    still = {a.kind for a in await store.alerts.open_alerts()}
    assert AlertKind.DEAD_LETTERS.value in still, "a hazards-only look leaves the other kinds as they are"
    assert AlertKind.UPLINK_NEAR_FULL.value in still
    await alerts.check(T0 + 67 * SECOND)
    assert AlertKind.DEAD_LETTERS.value not in {a.kind for a in await store.alerts.open_alerts()}


class Connections:
    """The broker's connections by user, as the management API would answer; ``away``: it does not."""

    def __init__(self) -> None:
        self.open: dict[str, int] = {}
        self.away = False
        self.asked = 0

    async def __call__(self) -> dict[str, int]:
        self.asked += 1
        if self.away:
            raise ConnectionError("management API unreachable")
        return self.open


async def test_a_robot_disconnected_is_raised_after_the_threshold_and_left_as_it_is_while_the_broker_is_away(
    store: Repositories,
) -> None:
    connections = Connections()
    thresholds = Thresholds(timedelta(seconds=60), 20.0, timedelta(hours=1), 0.8, 10 * SECOND)

    def api_process() -> Alerts:
        """The alerts of an API process: its memory of connections begins with it."""
        return Alerts(
            store.alerts,
            store.hazards,
            store.hazards,
            store.events,
            store.sites,
            thresholds,
            connections=connections,
        )

    alerts = api_process()
    for name in ("explorer1", "scout1"):
        await store.hazards.register_robot(name, "explorer")
    disconnected = AlertKind.ROBOT_DISCONNECTED.value

    def kinds(raised: list) -> list[tuple[str, str]]:
        return [(a.kind, a.subject) for a in raised if a.kind == disconnected]

    connections.open = {"explorer1": 1}
    assert kinds(await alerts.check(T0)) == []
    connections.open = {}
    assert kinds(await alerts.check(T0 + 9 * SECOND)) == [], "not yet: under the threshold"
    raised = await alerts.check(T0 + 10 * SECOND)
    assert kinds(raised) == [(disconnected, "robot explorer1")], "scout1 never connected: no alert"
    assert connections.asked == 3, "one call per check, whatever the team's size"

    connections.away = True
    connections.open = {"explorer1": 1}
    assert kinds(await alerts.check(T0 + 20 * SECOND)) == []
    [still] = [a for a in await store.alerts.open_alerts() if a.kind == disconnected]
    assert still.ended_at is None, "the broker away: the alert is left as it was"
    connections.away = False
    connections.open = {}
    restarted = api_process()  # it never saw explorer1 connected; the store holds its alert
    await restarted.check(T0 + 20 * SECOND)
    assert (await store.alerts.get_alert(still.id)).ended_at is None, "still away after a restart"
    connections.open = {"explorer1": 1}
    await alerts.check(T0 + 21 * SECOND)
    ended = await store.alerts.get_alert(still.id)
    assert ended is not None and ended.ended_at == T0 + 21 * SECOND, "connected again: ended"
    assert ended.acknowledged_by is None, "ended, it waits to be acknowledged"


async def test_a_sites_downlink_that_dropped_accounts_or_missions_is_alerted_on_again_when_it_drops_more(
    store: Repositories,
) -> None:
    thresholds = Thresholds(timedelta(seconds=60), 20.0, timedelta(seconds=60), 0.8)
    alerts = Alerts(
        store.alerts, store.hazards, store.hazards, store.events, store.sites, thresholds,
        housekeeping=store.housekeeping,
    )  # fmt: skip
    dropped = AlertKind.DOWNLINK_DROPPED.value

    def kinds(raised: list) -> list[tuple[str, str, float]]:
        return [(a.kind, a.subject, a.level) for a in raised if a.kind == dropped]

    # maps are dropped for the newest to go down: no alert for them
    await store.housekeeping.count_bounded({("overflow", "base1.downlink.maps maxlen"): 5}, T0)
    assert kinds(await alerts.check(T0)) == []
    await store.housekeeping.count_bounded({("overflow", "base1.downlink maxlen"): 2}, T0)
    [alert] = await alerts.check(T0 + SECOND)
    assert kinds([alert]) == [(dropped, "site base1", 2)]
    assert "fleetbus sites sync base1" in alert.detail
    assert await alerts.check(T0 + 2 * SECOND) == [], "raised once"
    await store.alerts.acknowledge(alert.id, "oper1", T0 + 3 * SECOND)
    await store.housekeeping.count_bounded({("overflow", "base1.downlink maxlen"): 1}, T0 + 4 * SECOND)
    assert kinds(await alerts.check(T0 + 5 * SECOND)) == [(dropped, "site base1", 3)], "more dropped: again"
