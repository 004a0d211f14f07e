"""Alerts in a real browser, on the real broker, worker and store: a robot's low battery shows in
the banner and on the Alerts page without a reload, and an operator acknowledges it there; who and
when is shown, and is what the store keeps."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.broker.accounts import Role
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import Browser, running_console
from tests.factories import status
from tests.support import Bus


def test_an_alert_shows_live_and_an_operator_acknowledges_it(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus, bus.settings.updated(alerts_check_s=0.2)) as console:
        console.user("oper1", UserRole.OPERATOR)
        browser.console_errors()  # what earlier tests left in the browser's log, read and left out
        console.log_in(browser, "oper1")
        browser.go(console.url("/console/alerts"))
        console.wait_live(browser)
        browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")

        explorer.publish("status", status(12.0))
        browser.until(lambda: browser.find("#alerts-open tr.kind-battery-low"), "the alert listed live")
        browser.until(lambda: "battery 12 % (low below 20 %)" in browser.text("#alerts-banner"), "the banner")
        [row] = browser.attributes("#alerts-open tr.kind-battery-low", "id")
        assert row is not None
        alert_id = int(row.removeprefix("alert-"))
        assert "robot explorer1" in browser.text(f"#{row} td.subject")

        before = datetime.now(timezone.utc).replace(microsecond=0)
        browser.click(f"#{row} button.acknowledge")
        browser.until(lambda: "acknowledged by oper1 at" in browser.text("#alerts-notice"), "the notice")
        browser.until(lambda: browser.text(f"#acknowledged-{alert_id} td.by") == "oper1", "who, listed")
        shown = datetime.strptime(browser.text(f"#acknowledged-{alert_id} td.at"), "%Y-%m-%d %H:%M:%S")
        at = shown.replace(tzinfo=timezone.utc)
        assert before <= at <= datetime.now(timezone.utc), (before, at)
        browser.until(lambda: not browser.find(f"#banner-alert-{alert_id}"), "gone from the banner")
        assert not browser.find(f"#{row}"), "no longer to acknowledge"
        assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"

        kept = console.run(lambda: console.service.repositories.alerts.get_alert(alert_id))
        assert kept is not None and kept.acknowledged_by == "oper1" and kept.acknowledged_at is not None
        assert kept.acknowledged_at - at < timedelta(seconds=1), "the time shown is the time kept (UTC)"
        # no htmx error (a swap into a replaced element, a refused request), no missing file
        assert browser.console_errors() == []
