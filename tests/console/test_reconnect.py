"""A dashboard cut off from the console and back: it shows, without a reload, what came meanwhile.

The browser reaches the console through a link the test cuts (``tests.link.NetworkLink``), as a
field network drops an operator's laptop; the broker, the worker, the robots and the console
carry on.
"""

from __future__ import annotations

import re
import time
from datetime import datetime, timezone
from urllib.parse import urlsplit

import pytest

from fleetbus.api.console.session import SESSION_COOKIE
from fleetbus.broker.accounts import Role
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import Browser, running_console
from tests.factories import hazard
from tests.link import NetworkLink
from tests.support import Bus, wait_for

#: How long the browser is cut off: a few seconds in the default suite (the browser notices at
#: once: its connection is dropped), the full minute under ``slow``.
CUTS = [pytest.param(3.0, id="3s"), pytest.param(60.0, id="60s", marks=pytest.mark.slow)]
EVENTS_DURING_CUT = 100


def live_state(browser: Browser) -> str | None:
    return browser.find("#live-status")[0].get_attribute("data-state")


@pytest.mark.parametrize("cut_s", CUTS)
def test_a_dashboard_cut_off_shows_all_it_missed_once_back(bus: Bus, browser: Browser, cut_s: float) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        assert console.service.settings.console_recent_events >= EVENTS_DURING_CUT, "the list holds them all"
        link = NetworkLink(urlsplit(console.base).port or 0).start()
        try:
            through_link = f"http://127.0.0.1:{link.port}"
            console.user("oper1", UserRole.OPERATOR)
            console.log_in(browser, "oper1", base=through_link)
            assert browser.driver.current_url == f"{through_link}/console/"
            assert browser.driver.get_cookie(SESSION_COOKIE), "the session cookie, through the link"
            console.wait_live(browser)
            explorer.publish("hazard", hazard(0, description="before the cut"))
            browser.until(lambda: "before the cut" in browser.texts("#events td.summary"), "the page live")
            browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")

            link.cut()
            cut_ends = time.monotonic() + cut_s
            browser.until(lambda: live_state(browser) == "reconnecting", "the page to say it is reconnecting")
            said = browser.text("#live-status")
            since = re.fullmatch(r"reconnecting… \(since (\d\d:\d\d:\d\d) UTC\)", said)
            assert since, f"the time it went down, in UTC: {said!r}"
            went = datetime.strptime(since.group(1), "%H:%M:%S")
            now = datetime.now(timezone.utc)
            seconds = [t.hour * 3600 + t.minute * 60 + t.second for t in (now, went)]
            apart = abs(seconds[0] - seconds[1])
            assert min(apart, 86_400 - apart) < 60, f"{said!r} at {now:%H:%M:%S} UTC"
            stored = bus.count()
            sent = explorer.publish_many(
                ("hazard", hazard(i, description=f"during the cut {i}")) for i in range(EVENTS_DURING_CUT)
            )
            wait_for(lambda: bus.count() == stored + EVENTS_DURING_CUT, what="the events stored")
            wait_for(lambda: time.monotonic() >= cut_ends, timeout=cut_s + 10, what=f"a {cut_s:g} s cut")
            assert live_state(browser) == "reconnecting", "still cut off"
            assert not any("during the cut" in text for text in browser.texts("#events td.summary"))

            link.restore()
            browser.until(lambda: live_state(browser) == "live", "the page live again", timeout=30)
            rows = {f"event-{e.robot_id}-{e.epoch}-{e.seq}" for e in sent}
            browser.until(
                lambda: rows <= {row.get_attribute("id") for row in browser.find("#events tr")},
                f"the {EVENTS_DURING_CUT} events of the cut on the page",
            )
            summaries = browser.texts("#events td.summary")
            assert sorted(s for s in summaries if "during the cut" in s) == sorted(
                f"during the cut {i}" for i in range(EVENTS_DURING_CUT)
            ), "each once"
            assert summaries[0] == f"during the cut {EVENTS_DURING_CUT - 1}", "the newest first"
            assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"
            assert "oper1" in browser.text(".who")
        finally:
            link.stop()
