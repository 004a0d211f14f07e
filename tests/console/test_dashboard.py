"""The dashboard in a real browser, on the real broker, worker and store."""

from __future__ import annotations

import time

from fleetbus.broker.accounts import Role
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import Browser, running_console
from tests.factories import hazard
from tests.support import Bus

XSS = "<script>alert(1)</script>"


def test_a_published_hazard_appears_live_without_a_reload(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        assert browser.driver.current_url == console.url("/console/")
        console.wait_live(browser)
        browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")

        explorer.publish("hazard", hazard(0, description="Smoke in corridor B"))
        published = time.monotonic()

        browser.until(
            lambda: any("Smoke in corridor B" in row for row in browser.texts("#events tr")),
            "the hazard's row on the dashboard",
        )
        # the promise is 2 s from publishing; allow the worker's first batch on a loaded machine
        assert time.monotonic() - published < 10
        assert "explorer1" in browser.text("#events tr")
        browser.until(
            lambda: browser.text("#hazards-held") + browser.text("#hazards-announced") != "00",
            "the hazard counted by state",
        )
        assert "explorer" in browser.text("#robot-explorer1")
        assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"


def test_what_a_robot_sent_shows_as_text_never_as_markup(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        console.wait_live(browser)
        explorer.publish("hazard", hazard(0, description=XSS))
        browser.until(lambda: XSS in browser.texts("#events td.summary"), "the hazard, live")
        browser.go(console.url("/console/"))
        browser.until(lambda: XSS in browser.texts("#events td.summary"), "the hazard, as first rendered")
        assert browser.find("#events script") == []
        assert not any("alert" in line for line in browser.console_errors())
