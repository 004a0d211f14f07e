"""Evaluation in a real browser, on the real broker, worker, recorder and store: the per-behaviour
table and its charts from published behaviour outcomes, the recording's growth charts, and who
may open the page."""

from __future__ import annotations

import httpx
import pytest

from fleetbus.api.console.session import CSRF_COOKIE
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EventType, RobotKind
from tests.console.support import PASSWORD, Browser, running_console
from tests.support import Bus, wait_for

BEHAVIOUR = EventType.BEHAVIOUR.value
#: (name, success, duration in seconds) as robots report them.
OUTCOMES = [
    ("grab", False, 12.0),
    ("grab", True, 10.0),
    ("place", True, 4.0),
    ("grab", False, 14.0),
    ("place", True, 4.0),
]


def test_the_table_counts_each_behaviour_and_the_charts_draw_each(bus: Bus, browser: Browser) -> None:
    with bus.worker(), bus.recorder(sample_interval=0.2), running_console(bus) as console:
        console.user("planner1", UserRole.PLANNER)
        with bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER)) as explorer1:
            for name, success, duration in OUTCOMES:
                body = {"name": name, "success": success, "duration_s": duration}
                explorer1.publish(BEHAVIOUR, body)
        wait_for(lambda: len(bus.recorded(BEHAVIOUR)) == len(OUTCOMES), what="the outcomes recorded")
        wait_for(
            lambda: len(console.run(console.service.recording.samples)) >= 3,
            what="the recorder's size samples",
        )

        console.log_in(browser, "planner1")
        assert browser.texts("header nav a") == ["Dashboard", "Missions", "Evaluation"], "a planner's pages"
        browser.go(console.url("/console/evaluation"))

        def row(name: str) -> dict[str, str]:
            cells = f"#outcomes tr[data-behaviour={name}] td"
            return {cell.get_attribute("class").split()[-1]: cell.text for cell in browser.find(cells)}

        assert [r.get_attribute("data-behaviour") for r in browser.find("#outcomes tr.outcome")] == [
            "grab",
            "place",
        ]
        grab, place = row("grab"), row("place")
        assert (grab["runs"], grab["successes"], grab["failures"], grab["rate"]) == ("3", "1", "2", "33.3 %")
        assert (grab["mean"], grab["deviation"]) == ("12.000", "1.633"), "population deviation of 12, 10, 14"
        assert (place["successes"], place["failures"], place["rate"], place["mean"]) == (
            "2",
            "0",
            "100.0 %",
            "4.000",
        )

        for chart in ("#rate-chart", "#duration-chart"):
            bars = browser.find(f"{chart} g.behaviour")
            assert [b.get_attribute("data-label") for b in bars] == ["grab", "place"], chart
        widths = [float(r.get_attribute("width")) for r in browser.find("#rate-chart g.behaviour rect")]
        assert widths[1] == pytest.approx(3 * widths[0], abs=1), "100 % is three times 33.3 %"
        assert "success rate (%)" in browser.texts("#rate-chart text.axis-label")
        assert any("duration (s)" in label for label in browser.texts("#duration-chart text.axis-label"))
        assert len(browser.find("#duration-chart g.behaviour line.whisker")) == 3, (
            "only grab's durations vary"
        )

        for chart, unit in (
            ("#growth-chart", "growth (MB per minute)"),
            ("#insert-chart", "inserts per minute"),
        ):
            assert browser.find(f"{chart} polyline.line"), chart
            assert set(browser.texts(f"{chart} text.axis-label")) == {"time (UTC)", unit}
        assert not any("Content Security Policy" in line for line in browser.console_errors())


def test_a_planner_may_open_evaluation_but_not_messages(bus: Bus) -> None:
    with running_console(bus) as console, httpx.Client(base_url=console.base, timeout=30) as http:
        console.user("planner1", UserRole.PLANNER)
        http.get("/console/login")
        form = {"username": "planner1", "password": PASSWORD, "csrf": http.cookies[CSRF_COOKIE]}
        assert http.post("/console/login", data=form).headers["location"] == "/console/"
        assert http.get("/console/evaluation").status_code == 200
        for path in (
            "/console/messages",
            "/console/messages/trace?message_id=x",
            "/console/messages/timeline?robot=explorer1",
            "/console/stream/messages",
        ):
            refused = http.get(path)
            assert refused.status_code == 403, path
        assert "may not use the messages page" in http.get("/console/messages").text
        assert 'href="/console/messages"' not in http.get("/console/evaluation").text, "not linked either"
