"""The console's tables and lists sorted and filtered in a real browser, and kept so while live
updates arrive: the missions list (live, filtered by state, use case and client), the dashboard's
newest events, the hazards page's cards."""

from __future__ import annotations

import uuid
from datetime import datetime, timedelta, timezone
from functools import partial

from selenium.webdriver.support.select import Select

from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventRecord
from tests.console.support import Browser, Console, running_console
from tests.console.test_missions import PLAN
from tests.factories import hazard
from tests.support import Bus


def shown(browser: Browser, rows: str) -> list[str]:
    """The ids of the rows (or cards) the page shows, in its order."""
    return browser.driver.execute_script(
        "const found = Array.from(document.querySelectorAll(arguments[0]));"
        "return found.filter((r) => !r.hidden).map((r) => r.id)",
        rows,
    )


def _shown_as(browser: Browser, rows: str, expected: list[str]) -> bool:
    return shown(browser, rows) == expected


def _sorted_by(browser: Browser, column: int, order: str, table: str = "missions-table") -> bool:
    """Whether ``table`` (the mission list) is sorted by ``column`` in ``order``, as its header says."""
    header = browser.find(f"#{table} th:nth-child({column + 1})")[0]
    values = browser.driver.execute_script(
        "return Array.from(document.querySelectorAll(arguments[1])).filter((r) => !r.hidden)"
        ".map((r) => r.cells[arguments[0]]).map((c) => c.dataset.sort ?? c.textContent.trim())",
        column,
        f"#{table} tbody tr",
    )
    return header.get_attribute("aria-sort") == order and values == sorted(
        values, reverse=order == "descending"
    )


def _states_shown(browser: Browser, expected: list[str]) -> bool:
    return browser.texts("#missions-rows tr:not([hidden]) .badge") == expected


def _mission(console: Console, owner: str, use_case: str, title: str, filed: bool = False) -> None:
    async def create() -> None:
        user = await console.service.repositories.users.get_user(owner)
        assert user is not None
        made = await console.service.missions.create(user, use_case, title, PLAN)
        if filed:
            await console.service.missions.transition(user, made.mission_id, MissionState.FILED)

    console.run(create)


def test_the_mission_list_is_live_sorted_and_filtered_by_state_use_case_and_client(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        for name, role in (
            ("client1", UserRole.CLIENT),
            ("client2", UserRole.CLIENT),
            ("super1", UserRole.SUPERVISOR),
        ):
            console.user(name, role)
        _mission(console, "client1", "hazard-response", "North yard", filed=True)  # m-1
        _mission(console, "client2", "survey", "South yard")  # m-2
        _mission(console, "client1", "survey", "East yard")  # m-3
        console.log_in(browser, "super1")
        browser.go(console.url("/console/missions"))
        console.wait_live(browser)
        rows = "#missions-rows tr"
        assert shown(browser, rows) == ["mission-m-3", "mission-m-2", "mission-m-1"], "newest first"
        headers = browser.texts("#missions-table thead th")
        assert headers == ["mission", "title", "use case", "state", "client", "last change"]
        states = [o.get_attribute("value") for o in browser.find("select[name=state] option")][1:]
        assert states == [state.value for state in MissionState], "the state filter in life-cycle order"
        for index, header in enumerate(headers):
            for order in ("ascending", "descending"):
                browser.click(f"#missions-table th:nth-child({index + 1}) button.sort")
                browser.until(partial(_sorted_by, browser, index, order), f"sorted by {header}, {order}")
                known = {  # the orders without ties
                    "title": ["mission-m-3", "mission-m-1", "mission-m-2"],  # East, North, South yard
                    "last change": ["mission-m-1", "mission-m-2", "mission-m-3"],  # m-1 filed first
                }.get(header)
                if known:  # a live update may have just replaced the rows: sorted again next frame
                    expected = known if order == "ascending" else known[::-1]
                    browser.until(partial(_shown_as, browser, rows, expected), f"{expected}")
                if header == "state":  # in life-cycle order (planning before filed), not by name
                    expected = ["planning", "planning", "filed"]
                    expected = expected if order == "ascending" else expected[::-1]
                    browser.until(partial(_states_shown, browser, expected), f"states {expected}")

        Select(browser.find("select[name=client]")[0]).select_by_value("client1")
        browser.until(lambda: shown(browser, rows) == ["mission-m-3", "mission-m-1"], "client1's missions")
        Select(browser.find("select[name=use_case]")[0]).select_by_value("survey")
        browser.until(lambda: shown(browser, rows) == ["mission-m-3"], "client1's surveys")
        Select(browser.find("select[name=use_case]")[0]).select_by_value("")
        Select(browser.find("select[name=state]")[0]).select_by_value("filed")
        browser.until(lambda: shown(browser, rows) == ["mission-m-1"], "client1's filed missions")
        Select(browser.find("select[name=state]")[0]).select_by_value("")

        browser.click("#missions-table th:nth-child(1) button.sort")  # by mission, ascending
        browser.until(lambda: shown(browser, rows) == ["mission-m-1", "mission-m-3"], "sorted by id")

        # new missions show without a reload, sorted and filtered as chosen
        browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")
        _mission(console, "client2", "survey", "West yard")  # m-4: another client's, filtered out
        _mission(console, "client1", "survey", "Roof")  # m-5
        browser.until(
            lambda: shown(browser, rows) == ["mission-m-1", "mission-m-3", "mission-m-5"],
            "m-5 live, in its place",
        )
        assert browser.find("#mission-m-4") and not browser.find("#mission-m-4")[0].is_displayed()
        browser.click("#missions-table th:nth-child(1) button.sort")  # again: descending
        browser.until(
            lambda: shown(browser, rows) == ["mission-m-5", "mission-m-3", "mission-m-1"], "reversed"
        )
        browser.fill("input.table-filter", "roof")
        browser.until(lambda: shown(browser, rows) == ["mission-m-5"], "the filter field")
        browser.fill("input.table-filter", "quay")

        # a client made after the page was drawn: its mission arrives live, and the client filter
        # offers it
        console.user("client3", UserRole.CLIENT)
        _mission(console, "client3", "survey", "Quay")  # m-6
        client_choices = "select[name=client] option"
        browser.until(lambda: "client3" in browser.texts(client_choices), "client3 offered as it arrives")
        Select(browser.find("select[name=client]")[0]).select_by_value("client3")
        browser.until(lambda: shown(browser, rows) == ["mission-m-6"], "client3's mission")
        assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"

        # a client's list shows its own missions only
        browser.reset()
        console.log_in(browser, "client1")
        browser.go(console.url("/console/missions"))  # a login lands on the dashboard
        console.wait_live(browser)
        browser.until(
            lambda: shown(browser, rows) == ["mission-m-5", "mission-m-3", "mission-m-1"],
            "client1's own only",
        )
        assert [o.text for o in browser.find("select[name=client] option")] == ["any", "client1"]


def _event(robot: str, seq: int, at: datetime) -> EventRecord:
    return EventRecord(
        robot_id=robot,
        epoch="e1",
        seq=seq,
        type="beacon",
        message_id=str(uuid.uuid4()),
        sent_at=at,
        received_at=at,
        body={"beacon_id": f"b{seq}", "rssi": -60},
        user_id=robot,
        exchange=f"{robot}.events",
        routing_key=f"{robot}.beacon",
    )


def test_the_dashboards_events_and_the_hazards_page_filter_and_sort(bus: Bus, browser: Browser) -> None:
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        for name, kind in (
            ("guide1", RobotKind.GUIDE),
            ("warden1", RobotKind.WARDEN),
            ("guide2", RobotKind.GUIDE),
        ):
            console.user(name, UserRole.ROBOT, kind)
        now = datetime.now(timezone.utc)
        events = console.service.repositories.events
        console.run(lambda: events.write_events([_event("guide1", 1, now), _event("guide2", 1, now)]))
        console.log_in(browser, "oper1")
        browser.go(console.url("/console/"))
        console.wait_live(browser)

        # the team: sorted by a column, again to reverse, and filtered by a word; a live render
        # may replace the team's table (and its filter) at any moment, so each action is one script,
        # and a click waits for the sort buttons the page gives a table once it is shown
        team = "#team-table tbody tr"
        sort_by = (
            "const sort = document.querySelector(`#team-table th:nth-child(${arguments[0]}) button.sort`);"
            "if (sort) { sort.click(); } return sort !== null"
        )

        def sort_team(column: int, what: str) -> None:
            browser.until(lambda: browser.driver.execute_script(sort_by, column), what)

        browser.until(lambda: len(shown(browser, team)) == 3, "the three robots")
        sort_team(2, "sorted by kind")
        browser.until(partial(_sorted_by, browser, 1, "ascending", "team-table"), "the team by kind")
        sort_team(1, "sorted by robot")
        browser.until(
            lambda: shown(browser, team) == ["robot-guide1", "robot-guide2", "robot-warden1"], "by robot"
        )
        sort_team(1, "sorted by robot, reversed")
        browser.until(
            lambda: shown(browser, team) == ["robot-warden1", "robot-guide2", "robot-guide1"], "reversed"
        )
        filter_by = (
            "const filter = document.getElementById('team-table').previousElementSibling;"
            "if (!filter || !filter.classList.contains('table-filter')) { return false; }"
            "filter.value = arguments[0]; filter.dispatchEvent(new Event('input', {bubbles: true}));"
            "return true"
        )
        browser.until(lambda: browser.driver.execute_script(filter_by, "warden"), "the team filtered")
        browser.until(lambda: shown(browser, team) == ["robot-warden1"], "the wardens only")
        rows = "#events tr"
        browser.until(lambda: len(shown(browser, rows)) == 2, "the two events")
        filters = browser.find("input.table-filter")
        assert len(filters) >= 2, "the team and the events tables have one each"
        events_filter = browser.driver.execute_script(
            "return document.getElementById('events-table').previousElementSibling"
        )
        events_filter.clear()
        events_filter.send_keys("guide2")
        browser.until(lambda: shown(browser, rows) == ["event-guide2-e1-1"], "guide2's events only")
        later = now + timedelta(seconds=1)
        console.run(lambda: events.write_events([_event("guide1", 2, later), _event("guide2", 2, later)]))
        browser.until(
            lambda: shown(browser, rows) == ["event-guide2-e1-2", "event-guide2-e1-1"],
            "guide2's new event, live",
        )
        assert len(browser.find(rows)) == 4, "guide1's new event arrived, hidden"

        async def hazards() -> None:
            store = console.service.repositories.hazards
            for seq, (robot, what) in enumerate(
                (("explorer1", "Gas leak"), ("explorer2", "Fire"), ("explorer1", "Smoke"))
            ):
                event = {"body": hazard(seq, description=what)}
                await store.add_hazard(
                    "default", robot, "e", seq, event, now + timedelta(seconds=seq), held=False
                )

        console.run(hazards)
        browser.go(console.url("/console/hazards"))
        cards = "#hazard-list > article"
        browser.until(lambda: len(shown(browser, cards)) == 3, "three hazards")
        newest = shown(browser, cards)
        Select(browser.find("select[data-sort-list=hazard-list]")[0]).select_by_value("detected:asc")
        browser.until(lambda: shown(browser, cards) == list(reversed(newest)), "oldest first")
        Select(browser.find("select[data-sort-list=hazard-list]")[0]).select_by_value("robot:asc")
        browser.fill("input[data-filter-list=hazard-list]", "explorer1")
        browser.until(lambda: len(shown(browser, cards)) == 2, "explorer1's hazards")
        assert all("explorer1" in browser.text(f"#{card}") for card in shown(browser, cards))
