"""The broker panel's message-rate charts: rates from the management API's samples, and the
dashboard charting them for the last hour from the real broker."""

from __future__ import annotations

import time
from datetime import datetime, timezone
from typing import Any

from fleetbus.api.console.broker_rates import rates_of
from fleetbus.schemas.roles import UserRole
from tests.console.support import Browser, running_console
from tests.support import Bus

MINUTE_MS = 60_000


def _samples(*counts: int, start_ms: int = 1_800_000_000_000) -> list[dict[str, int]]:
    """The counter's cumulative ``counts`` a minute apart, newest first (as the broker lists them)."""
    return [{"sample": count, "timestamp": start_ms + i * MINUTE_MS} for i, count in enumerate(counts)][::-1]


def test_a_rate_is_the_growth_between_neighbouring_samples_and_a_restart_counts_from_zero() -> None:
    found = rates_of({"message_stats": {"publish_details": {"samples": _samples(0, 60, 180, 30)}}})
    spans = found.spans["publish"]
    assert [rate for _, _, rate in spans] == [1.0, 2.0, 0.5], "60 and 120 a minute; 30 after a restart"
    assert spans[0][0] == datetime.fromtimestamp(1_800_000_000, timezone.utc), "oldest first, in UTC"
    assert [rate for _, _, rate in found.spans["deliver_get"]] == [0.0, 0.0, 0.0], "none delivered yet"
    assert found.newest("publish") == 0.5
    assert rates_of({}).spans == {"publish": [], "deliver_get": []}, "a virtual host with no traffic yet"


class Traffic:
    """Traffic on the test's virtual host, a message a second on a channel kept open: the broker
    keeps no rates of an idle virtual host, and counts a channel's publishes at its next statistics
    round, which a channel closed before it (on a loaded node, a round comes late) never reaches."""

    def __init__(self, channel: Any) -> None:
        self._channel = channel
        self._last = -float("inf")

    def publish(self) -> bool:
        if time.monotonic() - self._last >= 1:
            self._channel.basic_publish("", "nowhere", b"counted, though no queue takes it")
            self._last = time.monotonic()
        return True


def test_the_dashboard_charts_the_last_hours_rates_from_the_broker(bus: Bus, browser: Browser) -> None:
    with running_console(bus) as console, bus.admin_channel() as channel:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        console.wait_live(browser)
        traffic = Traffic(channel)
        charted = lambda: traffic.publish() and browser.find("svg#rate-publish")  # noqa: E731
        browser.until(charted, "the published rate charted", timeout=90)
        for chart in ("rate-publish", "rate-deliver_get"):
            points = browser.find(f"svg#{chart} circle.point")
            # an hour's samples a minute apart are 60 or 61 rates, as the hour's ends fall on the minutes
            assert 55 <= len(points) <= 61, f"{chart}: a rate a minute for an hour, not {len(points)}"
            assert "time (UTC)" in browser.find(f"svg#{chart}")[0].get_attribute("textContent")
        title = browser.find("#rate-publish-title")[0].get_attribute("textContent")
        assert title == "messages published to fleetbus"
