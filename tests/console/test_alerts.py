"""Alerts in a real browser, on the real broker, worker and store: a robot's low battery shows in
the banner and on the Alerts page without a reload, and each role that may acknowledges it there
(the others are refused); who and when is shown, and is what the store keeps."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.api.services.alerts import ACKNOWLEDGERS
from fleetbus.broker.accounts import Role
from fleetbus.schemas.roles import ACTIVE_ROLES, UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.alerts import Alert
from tests.console.support import Browser, Console, http_session, role_user, running_console
from tests.factories import status
from tests.support import Bus, wait_for

#: Who acknowledges, in the order the test has them do it.
ACTING = (UserRole.OPERATOR, UserRole.SUPERVISOR, UserRole.ADMIN)
#: Who may not: no console page of alerts, and a forged POST refused.
REFUSED = (UserRole.PLANNER, UserRole.CLIENT, UserRole.GUEST)


def test_an_alert_shows_live_and_each_role_that_may_acknowledges_it(bus: Bus, browser: Browser) -> None:
    """One low-battery alert per acknowledging role, on one worker and console: every other role's
    forged POST is refused and leaves them open; then each role acknowledges its own in the browser."""
    assert frozenset(ACTING) == ACKNOWLEDGERS
    assert frozenset(ACTING + REFUSED) == ACTIVE_ROLES - {UserRole.ROBOT}
    robots = {
        name: bus.robot(bus.add(name, Role.ROBOT, RobotKind.EXPLORER))
        for name in (f"explorer-{role.value}" for role in ACTING)
    }
    with bus.worker(), running_console(bus, bus.settings.updated(alerts_check_s=0.2)) as console:
        for role in ACTING + REFUSED:
            console.user_of(role)
        for robot in robots.values():
            robot.publish("status", status(12.0))

        def listing() -> list[Alert]:
            alerts = console.run(console.service.alerts.listing).unacknowledged
            return [alert for alert in alerts if alert.kind == "battery-low"]

        alerts = wait_for(lambda: len(listing()) == len(robots) and listing(), what="an alert per robot")
        for role in REFUSED:
            with http_session(console, role_user(role)) as http:
                for alert in alerts:
                    refused = http.post(f"/console/alerts/{alert.id}/acknowledge")
                    assert refused.status_code == 403, (role, refused.text)
        assert len(listing()) == len(robots), "the refused left every alert open"
        for role, robot in zip(ACTING, robots, strict=True):
            browser.reset()
            _acknowledges(console, browser, role_user(role), robot)
        assert listing() == []


def _acknowledges(console: Console, browser: Browser, name: str, robot: str) -> None:
    """``name`` acknowledges ``robot``'s low battery on the Alerts page, live: who and when shown
    and kept."""
    browser.console_errors()  # what earlier pages left in the browser's log, read and left out
    console.log_in(browser, name)
    browser.go(console.url("/console/alerts"))
    console.wait_live(browser)
    browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")
    rows = "#alerts-open tr.kind-battery-low"
    listed = lambda: f"robot {robot}" in " ".join(browser.texts(f"{rows} td.subject"))  # noqa: E731
    browser.until(listed, "the alert listed")
    assert "battery 12 % (low below 20 %)" in browser.text("#alerts-banner")
    subjects = zip(browser.attributes(rows, "id"), browser.texts(f"{rows} td.subject"), strict=True)
    [row] = [row_id for row_id, subject in subjects if f"robot {robot}" in subject]
    assert row is not None
    alert_id = int(row.removeprefix("alert-"))

    before = datetime.now(timezone.utc).replace(microsecond=0)
    browser.click(f"#{row} button.acknowledge")
    browser.until(lambda: f"acknowledged by {name} at" in browser.text("#alerts-notice"), "the notice")
    browser.until(lambda: browser.text(f"#acknowledged-{alert_id} td.by") == name, "who, listed")
    shown = datetime.strptime(browser.text(f"#acknowledged-{alert_id} td.at"), "%Y-%m-%d %H:%M:%S")
    at = shown.replace(tzinfo=timezone.utc)
    assert before <= at <= datetime.now(timezone.utc), (before, at)
    browser.until(lambda: not browser.find(f"#banner-alert-{alert_id}"), "gone from the banner")
    assert not browser.find(f"#{row}"), "no longer to acknowledge"
    assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"

    kept = console.run(lambda: console.service.repositories.alerts.get_alert(alert_id))
    assert kept is not None and kept.acknowledged_by == name and kept.acknowledged_at is not None
    assert kept.acknowledged_at - at < timedelta(seconds=1), "the time shown is the time kept (UTC)"
    # no htmx error (a swap into a replaced element, a refused request), no missing file
    assert browser.console_errors() == []
