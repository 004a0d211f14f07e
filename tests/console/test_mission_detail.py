"""A mission's page in a real browser, on the real broker, worker and store: thousands of sensor
readings recorded under the mission mapped, clustered and coloured by value; a reading a robot
publishes drawn live; a comment one role posts shown live to another, as text."""

from __future__ import annotations

import time
from datetime import datetime, timedelta, timezone

from fleetbus.broker.accounts import Account, Role
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.use_cases import machine_for
from fleetbus.workers.store.base import EventRecord
from tests.console.support import Browser, Console, http_session, report_live, running_console
from tests.support import Bus

PLAN = MissionPlan.model_validate(
    {"geofence": {"polygon": [{"x": 0, "y": 0}, {"x": 50, "y": 0}, {"x": 50, "y": 40}, {"x": 0, "y": 40}]}}
)
#: Readings already recorded when the page opens: what it must map in under a second.
RECORDED = 3000
#: Where they lie: the geofence's lower-left 20 m square (the live one lands far from them).
SPREAD = 20.0
#: The users the tests make, by name.
USERS = {
    "client1": UserRole.CLIENT,
    "super1": UserRole.SUPERVISOR,
    "oper1": UserRole.OPERATOR,
    "oper2": UserRole.OPERATOR,
    "planner1": UserRole.PLANNER,
    "admin1": UserRole.ADMIN,
    "visitor1": UserRole.GUEST,
}
T0 = datetime(2026, 11, 28, 1, 0, tzinfo=timezone.utc)


def spot(i: int) -> tuple[float, float]:
    """Where the ``i``-th recorded reading was taken: spread over the square, fixed."""
    return (i * 7919 % 1000) / 1000 * SPREAD, (i * 104729 % 1000) / 1000 * SPREAD


def reading(value: float, x: float, y: float) -> dict[str, object]:
    return {"quantity": "depth", "value": value, "unit": "m", "pose": {"x": x, "y": y}}


def recorded(mission_id: str) -> list[EventRecord]:
    """Depth soundings of an earlier run of explorer1, as the worker stored them under the mission."""
    records = []
    for i in range(RECORDED):
        x, y = spot(i)
        at = T0 + timedelta(milliseconds=i)
        records.append(
            EventRecord(
                "explorer1", "20261128T010000000Z-00000001", i, "measurement", f"m-{i}", at, at,
                reading(2.0 + (x + y) / 5, x, y), "explorer1", "explorer1.events",
                "explorer1.measurement", mission_id,
            )
        )  # fmt: skip
    return records


def in_progress_with_explorer(console: Console) -> str:
    """client1's survey, started, explorer1 mounted by oper1, who checked in."""
    service = console.service

    async def go() -> str:
        users = service.repositories.users
        client, supervisor, operator = [await users.get_user(n) for n in ("client1", "super1", "oper1")]
        assert client and supervisor and operator
        mission = await service.missions.create(client, "survey", "Sound the harbour", PLAN)
        await service.missions.transition(supervisor, mission.mission_id, MissionState.IN_PROGRESS)
        await service.channels.mount(operator, "explorer1", mission.mission_id)
        await service.channels.check_in(operator, mission.mission_id)
        await service.repositories.events.write_events(recorded(mission.mission_id))
        return mission.mission_id

    return console.run(go)


def robot_url(console: Console, name: str) -> str:
    user = console.run(lambda: console.service.repositories.users.get_user(name))
    assert user is not None
    return console.service.accounts.broker_credentials(user).amqp_url


def points(browser: Browser) -> int:
    return int(browser.attributes("#mission-map", "data-points")[0] or 0)


def test_readings_are_mapped_clustered_and_live_and_comments_reach_other_roles(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        for name in ("client1", "super1", "oper1", "visitor1"):
            console.user(name, USERS[name])
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        mission = in_progress_with_explorer(console)
        page = console.url(f"/console/missions/{mission}")

        with bus.worker():  # users made first: explorer1's events have their shard
            browser.console_errors()  # read (and so cleared): an earlier test's pages' are not ours
            console.log_in(browser, "client1")
            browser.go(page)
            browser.until(lambda: points(browser) == RECORDED, f"the {RECORDED} recorded readings mapped")
            loaded_ms = int(browser.attributes("#mission-map", "data-loaded-ms")[0] or 0)
            print(f"\n{RECORDED} readings loaded and clustered {loaded_ms} ms after the page's start")
            assert loaded_ms > 0, "the page says when its readings were mapped"  # how fast: bench, not here
            clusters = [int(n or 0) for n in browser.attributes(".mp-cluster", "textContent")]
            assert clusters and sum(clusters) <= RECORDED, "clustered"
            assert len(clusters) < 200, f"{len(clusters)} clusters for {RECORDED} readings"
            assert len(browser.find("#mission-legend li")) == 9
            deepest = max(2.0 + (x + y) / 5 for x, y in map(spot, range(RECORDED)))
            assert browser.text("#mission-range") == f"depth (m): 2 to {deepest:.3g}"
            console.wait_live(browser)

            explorer = bus.robot(Account("explorer1", Role.ROBOT, robot_url(console, "explorer1")))
            published = time.monotonic()
            explorer.publish("measurement", reading(14.5, 45.0, 35.0))  # deeper than any, far off
            browser.until(lambda: points(browser) == RECORDED + 1, "the new reading mapped")
            shown = time.monotonic() - published
            report_live("the new reading on the mission's map", shown)
            browser.until(
                lambda: browser.find("path.mp-point.mp-bin-8"), "the new reading drawn, deepest colour"
            )
            assert browser.text("#mission-range") == "depth (m): 2 to 14.5", "the scale widened"

            # a comment by the operator reaches the client's open page, as text
            with http_session(console, "oper1") as operator:
                posted = operator.post(
                    f"/console/missions/{mission}/comments",
                    data={"text": "Soundings done <script>alert(1)</script>\nnext: the pier"},
                )
                assert posted.status_code == 303, posted.text
            browser.until(
                lambda: "Soundings done" in browser.text("#mission-thread"), "the operator's comment"
            )
            comment = browser.text("#mission-thread li.comment")
            assert "oper1 operator" in comment and "UTC" in comment
            assert "<script>alert(1)</script>\nnext: the pier" in comment, "as typed, two lines"
            assert browser.find("#mission-thread script") == []

            # the client answers through the form; the operator's page shows it
            browser.fill("#comment-text", "Thank you, the pier tomorrow.")
            browser.click("button[data-action=comment]")
            browser.until(lambda: "Thank you" in browser.text("#mission-thread"), "the client's comment")
            assert "Comment added." in browser.text("main")
            with http_session(console, "visitor1") as guest:
                seen = guest.get(f"/console/missions/{mission}").text
                assert "Thank you, the pier tomorrow." in seen and 'data-action="comment"' not in seen
                refused = guest.post(f"/console/missions/{mission}/comments", data={"text": "may I?"})
                assert refused.status_code == 403 and "role guest may not comment" in refused.text
                # a guest reads the mission list, not the robots' readings (as GET /missions/{id}/events)
                assert 'id="mission-sensors"' not in seen
                readings = guest.get(f"/console/missions/{mission}/points")
                assert readings.status_code == 403 and "guest may not read" in readings.text, readings.text
            assert len(console.run(lambda: console.service.repositories.comments.comments(mission))) == 2
            assert browser.console_errors() == []


def test_each_role_sees_the_steps_and_controls_it_may_use_and_its_comments_reach_the_client(
    bus: Bus, browser: Browser
) -> None:
    """A planner, an admin and a supervisor on an in-progress mission's page: the step buttons are
    those of its role, the mount form an operator's only, the Unmount button a supervisor's (and
    an operator's for the robots it mounted: not another operator's); the supervisor's and the
    planner's comments, made in the browser, are on the client's page."""
    with running_console(bus) as console:
        for name in ("client1", "super1", "oper1", "oper2", "planner1", "admin1"):
            console.user(name, USERS[name])
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        mission = in_progress_with_explorer(console)
        page = console.url(f"/console/missions/{mission}")
        steps = machine_for("survey").steps_from(MissionState.IN_PROGRESS)
        for name in ("planner1", "admin1", "super1", "oper2"):
            role = USERS[name]
            browser.reset()
            console.log_in(browser, name)
            browser.go(page)
            browser.until(lambda: browser.find("#mission-mounts #mount-explorer1"), f"{name}: the page")
            buttons = browser.attributes("#mission-machine button[data-to]", "data-to")
            assert buttons == [step.target.value for step in steps if role in step.roles], name
            assert bool(browser.find("#mount-form, #mount-none")) == (role is UserRole.OPERATOR), name
            unmounts = browser.find("button[data-unmount=explorer1]")
            assert bool(unmounts) == (role is UserRole.SUPERVISOR), f"{name}: explorer1 is oper1's"
            assert browser.find("button[data-action=comment]"), f"{name} comments"
            if role in (UserRole.SUPERVISOR, UserRole.PLANNER):
                _comment(browser, f"{name} was here")
        browser.reset()
        console.log_in(browser, "client1")
        browser.go(page)
        comments = browser.until(lambda: browser.texts("#mission-thread li.comment"), "the thread")
        assert [" ".join(c.split()[:2]) for c in comments] == ["planner1 planner", "super1 supervisor"]
        assert [c.splitlines()[-1] for c in comments] == ["planner1 was here", "super1 was here"]


def _comment(browser: Browser, text: str) -> None:
    """Comment through the open mission page's form; the thread shows it."""
    browser.fill("#comment-text", text)
    browser.click("button[data-action=comment]")
    browser.until(lambda: text in browser.text("#mission-thread"), f"the comment {text!r}")
