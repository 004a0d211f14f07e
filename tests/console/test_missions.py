"""The missions pages in a real browser and over HTTP: a new mission walked through its states by
the roles that may take each step, robots mounted and operators checked in; the buttons a role may
not press are neither shown nor accepted."""

from __future__ import annotations

import re

from selenium.webdriver.support.ui import Select

from fleetbus.api.console.session import CSRF_HEADER
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.missions import Mission
from tests.console.support import Browser, Console, http_session, running_console
from tests.support import Bus

PLAN = MissionPlan.model_validate(
    {
        "geofence": {"polygon": [{"x": 0, "y": 0}, {"x": 50, "y": 0}, {"x": 50, "y": 40}]},
        "risk_assessment": {"level": "low", "summary": "open field"},
    }
)


def mission(console: Console, mission_id: str = "m-1") -> Mission:
    return console.run(lambda: console.service.missions.get_any(mission_id))


def state(browser: Browser) -> str:
    return browser.text("#mission-state")


def step(browser: Browser, target: str) -> None:
    """Press the button of the step to ``target`` and wait for the page to show it taken."""
    browser.click(f"button[data-to={target}]")
    browser.until(lambda: state(browser) == target, f"the mission {target}")


def as_user(console: Console, browser: Browser, name: str, path: str = "/console/missions/m-1") -> None:
    console.log_in(browser, name)
    browser.go(console.url(path))


def test_a_new_mission_walks_its_states_through_the_buttons_of_each_role(bus: Bus, browser: Browser) -> None:
    with running_console(bus) as console:
        for name, role in (
            ("client1", UserRole.CLIENT),
            ("super1", UserRole.SUPERVISOR),
            ("oper1", UserRole.OPERATOR),
        ):
            console.user(name, role)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)

        console.log_in(browser, "client1")
        assert browser.driver.current_url == console.url("/console/"), "every role lands on the dashboard"
        browser.click("a[href='/console/missions/new']")
        browser.fill("input[name=title]", "Survey the north yard")
        browser.fill("textarea[name=geofence]", "0 0\n50 0\n50 40\n0 40")
        browser.fill("textarea[name=points_of_interest]", "gate, 5, 5, north entrance")
        Select(browser.find("select[name=risk_level]")[0]).select_by_value("medium")
        browser.fill("textarea[name=risk_summary]", "forklifts in the yard")
        browser.click(".mission-form button[type=submit]")
        browser.until(lambda: browser.find("#confirm-form"), "the summary")
        assert "gate (5.0, 5.0) north entrance" in browser.text("#summary-pois")
        browser.click("button[data-action=confirm]")
        browser.until(lambda: state(browser) == "planning", "the new mission's page")
        assert browser.driver.current_url.startswith(console.url("/console/missions/m-1"))
        assert "gate (5.0, 5.0) north entrance" in browser.text("#mission-plan")
        assert "medium" in browser.text("#mission-plan")
        assert browser.find("button[data-to=approved]") == [], "not from planning"
        step(browser, "filed")
        assert browser.find("button[data-to]") and all(
            b.get_attribute("data-to") == "closed" for b in browser.find("button[data-to]")
        ), "filed: the client may only cancel"

        as_user(console, browser, "super1")
        step(browser, "approved")
        step(browser, "in_progress")

        as_user(console, browser, "oper1")
        browser.click("button[data-action=mount]")
        browser.until(lambda: browser.find("#mount-explorer1"), "explorer1 mounted")
        assert "oper1" in browser.text("#mount-explorer1")
        browser.click("button[data-action=check-in]")
        browser.until(lambda: browser.find("#check-in-oper1"), "oper1 checked in")
        assert "explorer1" in browser.text("#check-in-oper1"), "its mounted robot is recorded"
        step(browser, "interrupted")

        as_user(console, browser, "super1")
        step(browser, "in_progress")

        as_user(console, browser, "oper1")
        browser.click("button[data-action=check-out]")
        browser.until(lambda: state(browser) == "reviewing", "the last operator out: reviewing")
        browser.click("button[data-unmount=explorer1]")
        browser.until(lambda: "No robot mounted." in browser.text("#mission-mounts"), "explorer1 unmounted")

        as_user(console, browser, "client1")
        step(browser, "closed")
        assert "None: the mission is over." in browser.text("#mission-machine")

        history = console.run(lambda: console.service.repositories.missions.mission_history("m-1"))
        assert [(change.target.value, change.by) for change in history] == [
            ("planning", "client1"),
            ("filed", "client1"),
            ("approved", "super1"),
            ("in_progress", "super1"),
            ("interrupted", "oper1"),
            ("in_progress", "super1"),
            ("reviewing", "fleetbus"),
            ("closed", "client1"),
        ]
        browser.go(console.url("/console/missions"))
        assert "closed" in browser.text("#mission-m-1")


def forms(page: str) -> list[str]:
    """The actions of the page's forms, but logging out and commenting (every role that may
    comment has that form: tests/console/test_mission_detail.py)."""
    actions = re.findall(r'<form[^>]*action="([^"]+)"', page)
    return [action for action in actions if action != "/console/logout" and not action.endswith("/comments")]


def test_a_role_that_may_not_take_a_step_sees_no_button_and_gets_403(bus: Bus) -> None:
    with running_console(bus) as console:
        for name, role in (
            ("client1", UserRole.CLIENT),
            ("client2", UserRole.CLIENT),
            ("super1", UserRole.SUPERVISOR),
            ("oper1", UserRole.OPERATOR),
            ("visitor1", UserRole.GUEST),
        ):
            console.user(name, role)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        missions = console.service.missions

        async def filed() -> None:
            owner = await console.service.repositories.users.get_user("client1")
            assert owner is not None
            created = await missions.create(owner, "hazard-response", "North yard", PLAN)
            await missions.transition(owner, created.mission_id, MissionState.FILED)

        console.run(filed)
        detail, steps, mounts = (f"/console/missions/m-1{path}" for path in ("", "/transitions", "/mounts"))
        with http_session(console, "oper1") as operator:
            page = operator.get(detail).text
            assert 'data-to="approved"' not in page and "approved: approve the mission" in page
            assert "(for supervisor)" in page
            refused = operator.post(steps, data={"to": "approved"})
            assert refused.status_code == 403
            assert "filed -&gt; approved (approve the mission) is for supervisor, not operator" in (
                refused.text
            )
            too_early = operator.post(mounts, data={"robot": "explorer1"})
            assert too_early.status_code == 409 and "robots can be mounted when it is" in too_early.text
        with http_session(console, "visitor1") as guest:
            page = guest.get(detail)
            assert page.status_code == 200 and forms(page.text) == [], "a guest reads, presses nothing"
            assert "North yard" in guest.get("/console/missions").text
            assert 'href="/console/missions/new"' not in guest.get("/console/missions").text
            refused = guest.post(steps, data={"to": "approved"})
            assert refused.status_code == 403 and "may not use the mission state buttons" in refused.text
            assert guest.get("/console/missions/new").status_code == 403
            new = {"title": "x", "use_case": "survey"}
            assert guest.post("/console/missions", data=new).status_code == 403
            assert guest.post("/console/missions/summary", data=new).status_code == 403
            assert guest.get("/console/missions/new/map/1.png").status_code == 403
            assert guest.post(mounts, data={"robot": "explorer1"}).status_code == 403
        with http_session(console, "client2") as other:
            assert other.get(detail).status_code == 403, "another client's mission"
            assert other.post(steps, data={"to": "closed"}).status_code == 403
        assert mission(console).state is MissionState.FILED, "nothing changed"

        with http_session(console, "super1") as supervisor:
            assert 'data-to="approved"' in supervisor.get(detail).text
            assert supervisor.post(steps, data={"to": "approved"}).status_code == 303
        with http_session(console, "oper1") as operator:
            early = operator.post("/console/missions/m-1/check-in")
            assert early.status_code == 409 and "operators check in while it is in_progress" in early.text
            assert forms(operator.get(detail).text) == [mounts], "approved: an operator mounts, no more"
        assert mission(console).state is MissionState.APPROVED


def test_a_plan_that_is_not_valid_is_refused_with_its_reason_and_nothing_is_created(bus: Bus) -> None:
    with running_console(bus) as console:
        console.user("plan1", UserRole.PLANNER)
        with http_session(console, "plan1") as planner:
            form = {"title": "Yard", "use_case": "survey", "geofence": "0 0\n50 0", "risk_level": ""}
            outside = {**form, "geofence": "0 0\n50 0\n0 40", "points_of_interest": "gate, 60, 5"}
            # the summary refuses what the HTTP API refuses, with the API's reason, storing nothing
            api = {"Authorization": f"Bearer {console.session('plan1')}"}
            for bad, polygon, pois, reason in (
                (form, [[0, 0], [50, 0]], [], "geofence.polygon: List should have at least 3 items"),
                (
                    outside,
                    [[0, 0], [50, 0], [0, 40]],
                    [{"name": "gate", "x": 60, "y": 5}],
                    "points_of_interest.0 'gate' (60.0, 5.0) is outside the geofence",
                ),
            ):
                plan = {
                    "geofence": {"polygon": [{"x": x, "y": y} for x, y in polygon]},
                    "points_of_interest": pois,
                }
                body = {"title": "Yard", "use_case": "survey", "plan": plan}
                by_api = planner.post("/missions", json=body, headers=api)
                assert by_api.status_code == 422 and reason in by_api.json()["detail"]
                summary = planner.post("/console/missions/summary", data=bad)
                assert summary.status_code == 422 and "confirm-form" not in summary.text
                assert reason.replace("'", "&#39;") in summary.text
                assert 'action="/console/missions/summary"' in summary.text, "the form again"
            assert "0 0\n50 0" in summary.text and "gate, 60, 5" in summary.text, "what was typed is kept"
            assert console.run(console.service.repositories.missions.missions) == []

            refused = planner.post("/console/missions", data=form)  # Confirm checks again
            assert refused.status_code == 422
            assert "geofence.polygon: List should have at least 3 items" in refused.text
            assert "0 0\n50 0" in refused.text, "what was typed is kept"
            garbled = planner.post("/console/missions", data={**form, "geofence": "0 0\nfifty 0\n0 40"})
            assert "geofence line 2: expected 2 numbers, got &#39;fifty 0&#39;" in garbled.text
            unknown = planner.post("/console/missions", data={**form, "geofence": "", "use_case": "joyride"})
            assert unknown.status_code == 422 and "unknown use case &#39;joyride&#39;" in unknown.text
            assert console.run(console.service.repositories.missions.missions) == []
            valid = {**form, "geofence": "0 0\n50 0\n0 40"}
            summary = planner.post("/console/missions/summary", data=valid)
            assert summary.status_code == 200 and 'data-action="confirm"' in summary.text
            assert 'name="geofence" value="0 0\n50 0\n0 40"' in summary.text, "Confirm sends the same"
            assert console.run(console.service.repositories.missions.missions) == [], "not before Confirm"
            forged = planner.post("/console/missions", data=valid, headers={CSRF_HEADER: "not ours"})
            assert forged.status_code == 403 and "CSRF" in forged.text, "Confirm is CSRF-checked"
            assert console.run(console.service.repositories.missions.missions) == []
            created = planner.post("/console/missions", data=valid)
            assert created.status_code == 303
            assert created.headers["location"] == "/console/missions/m-1?done=created"
        assert mission(console).plan["geofence"]["polygon"][2] == {"x": 0.0, "y": 40.0}
