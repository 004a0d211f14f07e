"""Messages in a real browser, on the real broker, worker, recorder and store: the search, a
message's trace, a robot's timeline, and the live tail of what the user's stream receives."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime, timezone
from urllib.parse import urlencode

import httpx
import pytest
from selenium.webdriver.support.select import Select

from fleetbus.api.console.session import CSRF_COOKIE
from fleetbus.broker.accounts import Account, Role
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.envelope import Event
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EXPRESS_QUEUE, RECORDER_QUEUE, EventType, RobotKind
from fleetbus.schemas.use_cases import machine_for
from fleetbus.workers.store.recordings import RecordedMessage
from tests.api.support import PATHS, READY_PLAN
from tests.console.support import PASSWORD, Browser, Console, running_console
from tests.factories import hazard, status
from tests.support import Bus, wait_for

BEHAVIOUR = EventType.BEHAVIOUR.value


def outcome(name: str, success: bool, duration: float) -> dict[str, object]:
    return {"name": name, "object": "bottle", "success": success, "duration_s": duration}


@pytest.fixture
def recording(bus: Bus) -> Iterator[Console]:
    """The console with the worker and the recorder running; super1 (a supervisor) may use Messages."""
    with bus.worker(), bus.recorder(), running_console(bus) as console:
        console.user("super1", UserRole.SUPERVISOR)
        yield console


def all_recorded(bus: Bus, sentinel: Event) -> None:
    """Once ``sentinel`` (published after the test's messages were confirmed) is recorded, so is
    every message before it: the recorder takes its one queue in order, a batch at a time, each
    written whole before the next."""
    wait_for(
        lambda: bus.recorded(sentinel.type.value, message_id=str(sentinel.message_id)),
        what="the sentinel recorded",
    )


def recorded(bus: Bus, type: str, count: int, **query: object) -> list[RecordedMessage]:
    """The records of ``type``: exactly ``count`` (after :func:`all_recorded`)."""
    found = bus.recorded(type, **query)
    assert len(found) == count, f"{len(found)} {type} recorded, not {count}"
    return found


def row_keys(browser: Browser, table: str) -> list[str]:
    return [row.get_attribute("data-key") or "" for row in browser.find(f"{table} tr.record")]


def test_a_search_by_robot_type_and_condition_finds_exactly_the_matching_messages(
    bus: Bus, recording: Console, browser: Browser
) -> None:
    console = recording
    with (
        bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER)) as explorer1,
        bus.robot(bus.add("explorer2", kind=RobotKind.EXPLORER)) as explorer2,
    ):
        explorer1.publish(BEHAVIOUR, outcome("grab", False, 12.0))
        explorer1.publish(BEHAVIOUR, outcome("grab", True, 10.0))
        explorer1.publish(BEHAVIOUR, outcome("place", False, 3.0))
        explorer2.publish(BEHAVIOUR, outcome("grab", False, 9.0))  # another robot's failed grab
        explorer1.publish(BEHAVIOUR, outcome("grab", False, 14.0))
        all_recorded(bus, explorer2.publish("status", status(40)))  # not a behaviour: the sentinel
    every = recorded(bus, BEHAVIOUR, 5)
    expected = [
        r.key
        for r in every
        if r.robot_id == "explorer1"
        and r.document["body"]["name"] == "grab"
        and not r.document["body"]["success"]
    ]
    assert len(expected) == 2

    console.log_in(browser, "super1")
    browser.go(console.url("/console/messages"))
    Select(browser.find("select[name=type]")[0]).select_by_value(BEHAVIOUR)
    browser.fill("input[name=robot]", "explorer1")
    browser.fill("textarea[name=where]", "name=grab\nsuccess=false")
    browser.click("#search button[type=submit]")
    browser.until(lambda: browser.find("#results"), "the search's results")

    assert row_keys(browser, "#results") == expected, "exactly explorer1's failed grabs, oldest first"
    assert browser.texts("#results td.robot") == ["explorer1", "explorer1"]
    assert "2 behaviour messages" in browser.text("#search-count")
    assert "robot=explorer1" in browser.driver.current_url, "the search is in the address, to share or reload"

    browser.go(browser.driver.current_url)  # the same search, rendered whole
    assert row_keys(browser, "#results") == expected
    assert browser.find("textarea[name=where]")[0].get_attribute("value") == "name=grab\nsuccess=false"
    assert not any("Content Security Policy" in line for line in browser.console_errors())


def test_a_bad_condition_shows_the_parsers_error_in_the_form(
    bus: Bus, recording: Console, browser: Browser
) -> None:
    console = recording
    with bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER)) as explorer1:
        explorer1.publish(BEHAVIOUR, outcome("grab", False, 12.0))
        all_recorded(bus, explorer1.publish("status", status(40)))
    recorded(bus, BEHAVIOUR, 1)
    console.log_in(browser, "super1")
    browser.go(console.url("/console/messages"))
    Select(browser.find("select[name=type]")[0]).select_by_value(BEHAVIOUR)
    browser.fill("textarea[name=where]", "success")
    browser.click("#search button[type=submit]")
    browser.until(lambda: browser.find("#search-problem"), "the condition's problem shown")

    problem = browser.text("#search form #search-problem")
    assert "condition 'success': write FIELD=VALUE" in problem, problem
    assert browser.find("#results") == [], "no results for a search that was not run"
    assert browser.find("textarea[name=where]")[0].get_attribute("value") == "success", "what was typed stays"

    query = urlencode({"type": BEHAVIOUR, "since": "yesterday"})
    browser.go(console.url(f"/console/messages?{query}"))
    assert "since: cannot read 'yesterday' as a time" in browser.text("#search-problem")


def test_a_messages_trace_shows_its_validated_user_and_queues(
    bus: Bus, recording: Console, browser: Browser
) -> None:
    console = recording
    with bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER)) as explorer1:
        detected = explorer1.publish("hazard", hazard(0, description="Smoke in corridor B"))
        all_recorded(bus, explorer1.publish("status", status(40)))
    recorded(bus, "hazard", 1)
    wait_for(lambda: bus.count("hazard") == 1, what="the hazard stored")

    console.log_in(browser, "super1")
    browser.go(console.url(f"/console/messages?{urlencode({'type': 'hazard'})}"))
    browser.click("#results a.trace")
    browser.until(lambda: browser.find("#provenance"), "the trace")

    assert browser.text("#trace-user") == "explorer1"
    assert browser.text("#trace-exchange") == "explorer1.events"
    assert browser.text("#trace-routing-key") == "explorer1.hazard"
    assert f"epoch {detected.epoch} seq {detected.seq}" in browser.text("#trace-stored")
    queues = browser.texts("#trace-routes td.queue")
    assert set(queues) == {EXPRESS_QUEUE, RECORDER_QUEUE}, "a hazard takes the express lane; the recorder"
    outcomes = " ".join(browser.texts("#trace-routes tr.route"))
    assert "recorded at" in outcomes and f"seq {detected.seq}" in outcomes
    assert str(detected.message_id) in browser.text("#provenance h2")

    browser.go(console.url("/console/messages/trace?message_id=never-sent"))
    assert "never-sent was never recorded" in browser.text(".problem")


def test_a_robots_timeline_lists_its_messages_in_time_order(
    bus: Bus, recording: Console, browser: Browser
) -> None:
    console = recording
    with (
        bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER)) as explorer1,
        bus.robot(bus.add("explorer2", kind=RobotKind.EXPLORER)) as explorer2,
    ):
        explorer1.publish("status", status(90))
        explorer2.publish("status", status(50))
        explorer1.publish(BEHAVIOUR, outcome("grab", True, 4.0))
        explorer1.publish("hazard", hazard(1))
        explorer2.publish(BEHAVIOUR, outcome("grab", False, 5.0))
        explorer1.publish("status", status(88))
        # explorer2's: not on explorer1's timeline, and only its behaviour is counted
        all_recorded(bus, explorer2.publish("status", status(40)))
    mine = [
        *recorded(bus, "status", 2, robot_id="explorer1"),
        *recorded(bus, BEHAVIOUR, 1, robot_id="explorer1"),
        *recorded(bus, "hazard", 1, robot_id="explorer1"),
    ]
    recorded(bus, BEHAVIOUR, 1, robot_id="explorer2")
    in_order = sorted(mine, key=lambda r: (r.recorded_at, r.key))
    assert [r.type for r in in_order] == ["status", BEHAVIOUR, "hazard", "status"], "recorded as published"

    console.log_in(browser, "super1")
    browser.go(console.url("/console/messages"))
    browser.fill("#lookups input[name=robot]", "explorer1")
    browser.click("#lookups form[action$=timeline] button")
    browser.until(lambda: browser.find("#timeline-entries"), "the timeline")

    assert row_keys(browser, "#timeline-entries") == [r.key for r in in_order]
    assert browser.texts("#timeline-entries td.type") == ["status", BEHAVIOUR, "hazard", "status"]
    assert set(browser.texts("#timeline-entries td.direction")) == {"→"}, "all sent by explorer1"
    assert "explorer2" not in " ".join(browser.texts("#timeline-entries tr"))


def approved_mission(console: Console) -> str:
    """A hazard-response mission with a ready plan, walked to approved directly in the store."""
    store, now = console.service.repositories.missions, datetime.now(timezone.utc)
    mission = console.run(lambda: store.create_mission("hazard-response", "Fire", "client1", READY_PLAN, now))
    machine, mission_id = machine_for(mission.use_case), mission.mission_id
    for target in PATHS["hazard-response"]:
        if mission.state is MissionState.APPROVED:
            break
        source = machine.step(mission.state, target, None).source
        mission = console.run(
            lambda s=source, t=target: store.transition_mission(mission_id, s, t, "test", now)
        )
    assert mission.state is MissionState.APPROVED
    return mission_id


def robot_client(bus: Bus, console: Console, name: str) -> RobotClient:
    """A robot made through the service (as the admin would), connected with its broker account."""
    console.user(name, UserRole.ROBOT, RobotKind.EXPLORER)
    user = console.run(lambda: console.service.repositories.users.get_user(name))
    assert user is not None
    return bus.robot(Account(name, Role.ROBOT, console.service.accounts.broker_credentials(user).amqp_url))


def test_the_live_tail_shows_a_mounted_robots_message_and_never_an_unmounted_ones(
    bus: Bus, browser: Browser
) -> None:
    with bus.worker(), running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        mounted, unmounted = robot_client(bus, console, "explorer1"), robot_client(bus, console, "explorer2")
        operator = console.run(lambda: console.service.repositories.users.get_user("oper1"))
        mission_id = approved_mission(console)
        console.run(lambda: console.service.channels.mount(operator, "explorer1", mission_id))

        console.log_in(browser, "oper1")
        browser.go(console.url("/console/messages"))
        console.wait_live(browser)
        assert browser.texts(".following a.mounted") == ["explorer1"]

        unmounted.publish("status", status(11))  # the sentinel's counterpart: not in oper1's stream
        wait_for(lambda: bus.count("status", "explorer2") == 1, what="explorer2's status stored")
        unmounted.publish("beacon", {"beacon_id": "b7", "rssi": -61})  # beacons reach every stream
        mounted.publish("beacon", {"beacon_id": "b8", "rssi": -62})
        mounted.publish("status", status(77))

        def tail() -> str:
            return "\n".join(browser.texts("#tail tr"))

        browser.until(lambda: "explorer1.status" in tail(), "the mounted robot's status in the tail")
        browser.until(lambda: "explorer2.beacon" in tail(), "the other robot's beacon in the tail")
        assert "explorer2.status" not in tail(), "explorer2 is not mounted: its status never shows"
        assert '"battery_percent":77' in tail() and '"battery_percent":11' not in tail()

        browser.go(console.url("/console/messages"))  # as first rendered, from the store
        ids = browser.attributes("#tail tr", "id")
        assert len(ids) == len(set(ids)), "each message once (a mounted robot's beacon too)"
        routing_keys = sorted(browser.texts("#tail td.routing-key"))
        assert routing_keys == ["explorer1.beacon", "explorer1.status", "explorer2.beacon"]

        console.wait_live(browser)
        console.run(lambda: console.service.channels.unmount(operator, "explorer1"))
        browser.until(lambda: not browser.find(".following a.mounted"), "the unmount shown")
        mounted.publish("status", status(55))  # no longer in oper1's stream
        wait_for(lambda: bus.count("status", "explorer1") == 2, what="explorer1's second status stored")
        unmounted.publish("beacon", {"beacon_id": "b9", "rssi": -63})  # the sentinel
        browser.until(lambda: '"beacon_id":"b9"' in tail(), "the sentinel beacon in the tail")
        assert '"battery_percent":55' not in tail(), "unmounted: explorer1's status never shows"


def test_a_user_without_a_stream_is_shown_no_traffic(bus: Bus) -> None:
    with (
        bus.worker(),
        running_console(bus) as console,
        httpx.Client(base_url=console.base, timeout=30) as http,
    ):
        console.user("admin1", UserRole.ADMIN)
        with robot_client(bus, console, "explorer1") as explorer1:
            explorer1.publish("beacon", {"beacon_id": "b1", "rssi": -60})
        wait_for(lambda: bus.count("beacon") == 1, what="the beacon stored")
        http.get("/console/login")
        form = {"username": "admin1", "password": PASSWORD, "csrf": http.cookies[CSRF_COOKIE]}
        assert http.post("/console/login", data=form).status_code == 303
        page = http.get("/console/messages")
        assert page.status_code == 200 and "has no stream" in page.text
        assert 'id="tail-explorer1' not in page.text, "an administrator's account follows no stream"
