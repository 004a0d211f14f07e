"""The live map's Leaflet view in a real browser: a robot's trail over a chosen window from its
stored localisations (finding a lost robot by the path it reported), the time slider that shows
the team at a past moment, and a clicked robot followed as it moves; the map's files all from
fleetbus itself; for each role that watches the team (operator, admin, supervisor)."""

from __future__ import annotations

import re
import uuid
from datetime import datetime, timedelta, timezone

from fleetbus.broker.accounts import Role
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.hazards import DEFAULT_MISSION
from tests.console.support import Browser, Console, choose_trails, running_console, slide_map
from tests.console.test_map import at, drawn, open_map, stored_maps
from tests.factories import small_map, status
from tests.support import Bus

#: The lost robot's reported path: a pose every two minutes from 40 minutes ago to 2 minutes ago,
#: walking along x (x = 0, 1, 2, ... 19) at y = 2.
STEPS = 20


def _pose(robot: str, seq: int, type: str, at: datetime, x: float, y: float) -> EventRecord:
    """A ``localisation`` or ``status`` event of the robot at (x, y), as the worker stores it."""
    body = {"localised": True} if type == "localisation" else status(70.0)
    return EventRecord(
        robot_id=robot,
        epoch="e-path",
        seq=seq,
        type=type,
        message_id=str(uuid.uuid4()),
        sent_at=at,
        received_at=at,
        body={**body, "pose": {"x": x, "y": y}},
        user_id=robot,
        exchange=f"{robot}.events",
        routing_key=f"{robot}.{type}",
    )


def _store(console: Console, records: list[EventRecord]) -> None:
    console.run(lambda: console.service.repositories.events.write_events(records))


def _reported_path(console: Console, robot: str, now: datetime) -> None:
    """Its localisations, stored as the worker stores them."""
    at = [now - timedelta(minutes=40 - 2 * step) for step in range(STEPS)]
    _store(console, [_pose(robot, step, "localisation", at[step], float(step), 2.0) for step in range(STEPS)])


def _hazard_history(console: Console, now: datetime) -> None:
    """Hazard 1: seen 30 minutes ago (announced at once), claimed 10 and cleared 5 minutes ago, at
    (5, 6); hazard 2: seen 10 minutes ago and held since, at (9, 3)."""
    hazards = console.service.repositories.hazards

    async def history() -> None:
        for seq, (x, y, minutes, held) in enumerate(((5.0, 6.0, 30, False), (9.0, 3.0, 10, True))):
            event = {"body": {"pose": {"x": x, "y": y}, "description": f"Smoke {seq + 1}"}}
            at = now - timedelta(minutes=minutes)
            await hazards.add_hazard(DEFAULT_MISSION, "explorer1", "e-hazards", seq, event, at, held=held)
        await hazards.register_robot("warden1", RobotKind.WARDEN.value)
        await hazards.claim(DEFAULT_MISSION, 1, "warden1", now - timedelta(minutes=10))
        await hazards.mark_reached(DEFAULT_MISSION, 1, "warden1", now - timedelta(minutes=7))
        await hazards.mark_cleared(DEFAULT_MISSION, 1, "warden1", now - timedelta(minutes=5))

    console.run(history)


def _past_hazards(browser: Browser) -> dict[str, str]:
    """The hazards drawn as they were at the slider's moment: id to state then."""
    found = browser.find("[data-past-hazard]")
    return {mark.get_attribute("data-past-hazard"): mark.get_attribute("data-state") for mark in found}


def _offset_from_centre(browser: Browser, mark: str) -> float:
    """How far (px) the mark's glyph is from the map's centre."""
    return browser.driver.execute_script(
        "const v = document.getElementById('map-view').getBoundingClientRect();"
        "const mark = document.querySelector(`.leaflet-marker-icon[data-mark='${arguments[0]}'] .glyph`);"
        "const g = mark.getBoundingClientRect();"
        "const dx = g.x + g.width / 2 - (v.x + v.width / 2), dy = g.y + g.height / 2 - (v.y + v.height / 2);"
        "return Math.hypot(dx, dy);",
        mark,
    )


def _trail_shown(browser: Browser) -> None:
    """The last hour's trails chosen: explorer1's reported path drawn."""
    choose_trails(browser, 60)
    trail = browser.find("path.trail")
    assert len(trail) == 1 and trail[0].get_attribute("data-robot") == "explorer1"
    assert len(re.findall(r"[ML]", trail[0].get_attribute("d") or "")) >= 2, "a path, not a point"
    assert browser.text("#trail-grain") == "every pose"


def _follows(browser: Browser, explorer: RobotClient, x: float) -> None:
    """Click explorer1: the map centres on it, and stays centred as it moves to ``x``."""
    mark = ".leaflet-marker-icon[data-mark='mark-robot-explorer1']"
    browser.click(f"{mark} .glyph")
    browser.until(lambda: "Following explorer1" in browser.text("#map-following"), "following explorer1")
    browser.until(lambda: _offset_from_centre(browser, "mark-robot-explorer1") < 3, "centred on explorer1")
    explorer.publish("status", at(status(79.0), x, 8.0))
    browser.until(lambda: browser.attributes(mark, "data-x") == [f"{x:.3f}"], "the explorer moved")
    browser.until(lambda: _offset_from_centre(browser, "mark-robot-explorer1") < 3, "still centred on it")


def test_trails_the_time_slider_and_following_a_robot(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        explorer.publish("map", small_map())
        explorer.publish("status", at(status(80.0), 4.0, 5.0))
        stored_maps(bus, 1)
        now = datetime.now(timezone.utc)
        _reported_path(console, "explorer1", now)
        _hazard_history(console, now)
        browser.console_errors()  # what earlier tests' pages logged, read and set aside
        open_map(console, browser)
        browser.until(lambda: drawn(browser, "mark-robot-explorer1"), "the explorer on the map")
        assert browser.find("#map-time")[0].get_attribute("disabled") is not None, "no slider without trails"

        _trail_shown(browser)

        # three quarters along the last hour: 15 minutes ago, after the pose of 16 minutes ago (x 12)
        slide_map(browser, 750)
        browser.until(lambda: browser.find("[data-past=explorer1]"), "the explorer as it stood then")
        shown = browser.find("[data-past=explorer1]")[0].get_attribute("title")
        assert "explorer1 at (12.00, 2.00)" in shown, shown
        moment = browser.text("#map-moment")
        assert moment.endswith(" UTC"), moment
        then = datetime.strptime(moment, "%Y-%m-%d %H:%M:%S UTC").replace(tzinfo=timezone.utc)
        assert abs((now - timedelta(minutes=15) - then).total_seconds()) < 60, (moment, now)
        assert "in-past" in browser.find("#map-view")[0].get_attribute("class")
        # the hazards as they were then: hazard 1 announced, not yet claimed; hazard 2 not yet seen;
        # the live ones (hazard 1 cleared, 2 held) hidden meanwhile
        browser.until(lambda: _past_hazards(browser) == {"default-1": "announced"}, "hazard 1 as it was")
        assert not browser.find("[data-mark='mark-hazard-default-2']")[0].is_displayed()
        slide_map(browser, 890)  # 6.6 minutes ago: hazard 1 reached, hazard 2 held
        browser.until(
            lambda: _past_hazards(browser) == {"default-1": "reached", "default-2": "held"}, "both, then"
        )
        slide_map(browser, 950)  # 3 minutes ago: hazard 1 cleared
        browser.until(lambda: _past_hazards(browser) == {"default-2": "held"}, "hazard 1 gone, cleared")
        slide_map(browser, 1000)
        browser.until(lambda: browser.text("#map-moment") == "now", "back to now")
        assert browser.find("[data-past]") == [] and _past_hazards(browser) == {}
        assert browser.find("[data-mark='mark-hazard-default-2']")[0].is_displayed()

        # click the robot: the map centres on it and follows it as it moves
        _follows(browser, explorer, 8.5)

        # everything the map loaded came from the console's own server
        loaded = browser.driver.execute_script(
            "return performance.getEntriesByType('resource').map((entry) => entry.name)"
        )
        assert loaded and all(url.startswith(console.base) for url in loaded), loaded
        assert any("/static/console/vendor/leaflet-1.9.4/leaflet.js" in url for url in loaded)
        assert browser.console_errors() == []

        # the other roles that watch the team: the same trails, the same following
        for x, role in ((10.5, UserRole.ADMIN), (12.5, UserRole.SUPERVISOR)):
            browser.reset()
            open_map(console, browser, role=role)
            browser.until(lambda: drawn(browser, "mark-robot-explorer1"), f"{role.value}: the explorer")
            _trail_shown(browser)
            _follows(browser, explorer, x)
            assert browser.console_errors() == [], role


def test_the_trails_of_a_window_come_from_the_stored_statuses_and_localisations(bus: Bus) -> None:
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        now = datetime.now(timezone.utc)
        _reported_path(console, "explorer9", now)
        # a status of 3 and one of 1 minute ago (a status always says where the robot is)
        reports = [
            _pose("explorer9", STEPS + i, "status", now - timedelta(minutes=minutes), x, 2.5)
            for i, (minutes, x) in enumerate(((3, 18.5), (1, 20.0)))
        ]
        _store(console, reports)
        with console.http_as("oper1") as http:
            answer = http.get("/console/map/trails", params={"minutes": 10})
            assert answer.status_code == 200
            found = answer.json()
            # the last 10 minutes hold the localisations of 8, 6, 4 and 2 minutes ago (x 16 to 19)
            # and the statuses of 3 and 1 minute ago, in the order sent
            xs = [point[1] for point in found["robots"]["explorer9"]]
            assert xs == [16.0, 17.0, 18.0, 18.5, 19.0, 20.0]
            assert found["step"] == 0, "every pose of the window"
            assert http.get("/console/map/trails", params={"minutes": 0}).status_code == 422


def test_a_window_with_more_poses_than_an_answer_holds_is_each_robots_last_pose_of_each_step(
    bus: Bus, browser: Browser
) -> None:
    """A fleet's day of poses does not fit one answer: the window is cut into steps, as many as the
    budget gives each robot, and each robot's trail is its last pose of each, down to its newest."""
    with running_console(bus, bus.settings.updated(console_trail_points=8)) as console:
        now = datetime.now(timezone.utc)
        lost = ("explorer7", "explorer8", "explorer9")
        for robot in (*lost, "guide3"):  # the guide is in the team and reported no pose
            console.run(lambda robot=robot: console.service.repositories.hazards.register_robot(robot, None))
        for robot in lost:
            _reported_path(console, robot, now)
        # explorer7's newest pose is a status of a minute ago, after its last localisation
        _store(console, [_pose("explorer7", STEPS, "status", now - timedelta(minutes=1), 25.0, 2.0)])
        browser.console_errors()  # what earlier tests' pages logged, read and set aside
        open_map(console, browser)  # as oper1
        window = {"minutes": 60, "until": now.isoformat()}
        with console.http_as("oper1") as http:
            found = http.get("/console/map/trails", params=window).json()
        # 61 poses, 8 at most: 8 // 4 robots = 2 steps of 30 minutes; the first's last pose is of
        # 32 minutes ago (x 4), the second's the newest, of 2 minutes ago (x 19; explorer7's status
        # of a minute ago, x 25)
        assert found["step"] == 30 * 60 * 1000
        assert sorted(found["robots"]) == list(lost)
        for robot, newest in zip(lost, (25.0, 19.0, 19.0), strict=True):
            assert [point[1] for point in found["robots"][robot]] == [4.0, newest], robot
        assert found["since"] == round((now - timedelta(minutes=60)).timestamp() * 1000)

        # the map draws the three trails and says how coarse they are
        choose_trails(browser, 60)
        assert sorted(path.get_attribute("data-robot") for path in browser.find("path.trail")) == list(lost)
        assert browser.text("#trail-grain") == "a pose per 30 min"
        assert browser.console_errors() == []

    with running_console(bus) as console:  # the default budget holds the whole window (same store)
        with console.http_as("oper1") as http:
            found = http.get("/console/map/trails", params=window).json()
        assert found["step"] == 0
        assert [point[1] for point in found["robots"]["explorer7"]] == [*map(float, range(STEPS)), 25.0]
