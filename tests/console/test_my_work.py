"""Each role's own work on the dashboard, in a real browser on the real broker and store: the
missions that are theirs, the robots they mounted, their broker login with the password shown once
on request and a new one on request; the Accounts page, where an administrator sets a user's use
cases and a supervisor sees the registered robots without a control."""

from __future__ import annotations

from datetime import datetime, timezone

import pika.exceptions
import pytest

from fleetbus.api.console.session import SESSION_COOKIE
from fleetbus.api.services.accounts import User
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.missions import MissionPlan
from fleetbus.schemas.roles import WATCHERS, UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.schemas.use_cases import machine_for
from tests.console.support import Browser, Console, role_user, running_console, shown_once
from tests.support import Bus


def _open_as(console: Console, browser: Browser, name: str, path: str) -> None:
    """``path`` in a fresh browser with a session of ``name`` (minted, as the login form makes one)."""
    browser.reset()
    browser.go(console.url("/console/login"))
    browser.driver.add_cookie({"name": SESSION_COOKIE, "value": console.session(name)})
    browser.go(console.url(path))
    browser.until(lambda: name in browser.text(".who"), f"{path} as {name}")


def _user(console: Console, name: str) -> User:
    user = console.run(lambda: console.service.repositories.users.get_user(name))
    assert user is not None
    return user


def _broker_url(console: Console, name: str) -> str:
    return console.service.accounts.broker_credentials(_user(console, name)).amqp_url


def test_each_role_sees_its_own_work_and_its_broker_password_once_on_request(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.user("client1", UserRole.CLIENT)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        service = console.service

        async def setup() -> str:
            client = await service.repositories.users.get_user("client1")
            assert client is not None
            mission = await service.missions.create(client, "survey", "North yard", MissionPlan())
            now = datetime.now(timezone.utc)
            await service.repositories.channels.mount("explorer1", "oper1", mission.mission_id, now)
            return mission.mission_id

        mission_id = console.run(setup)
        old_url = _broker_url(console, "oper1")
        with console.http_as("oper1") as http:
            for asked in ("show", "new"):
                refused = http.post(f"/console/account/broker-password/{asked}")
                assert refused.status_code == 403 and "CSRF" in refused.text, asked
        assert _broker_url(console, "oper1") == old_url, "refused before anything changed"

        console.log_in(browser, "oper1")
        assert browser.driver.current_url == console.url("/console/")
        row = f"#my-mission-{mission_id}"
        assert "you mounted explorer1" in browser.text(f"{row} .why")
        assert mission_id in browser.text("#my-mount-explorer1")
        assert browser.find("#team"), "an operator watches the team too"
        oper = console.run(lambda: service.repositories.users.get_user("oper1"))
        assert oper is not None
        assert browser.text("#my-broker-url") == service.accounts.broker_address(oper)
        old_password = service.accounts.broker_credentials(oper).password
        assert old_password not in browser.driver.page_source, "not on the page until asked for"

        password, url = shown_once(browser, "#show-broker-password")
        assert (password, url) == (old_password, old_url)

        browser.go(console.url("/console/"))
        new_password, new_url = shown_once(browser, "#new-broker-password")
        assert new_password != old_password and new_url == _broker_url(console, "oper1")
        connection = blocking_connection(new_url)  # the new password logs in, with its permissions
        connection.channel().queue_declare("oper1.inbox", passive=True)
        connection.close()
        with pytest.raises(pika.exceptions.ProbableAuthenticationError):
            blocking_connection(old_url)

        _open_as(console, browser, "client1", "/console/")
        assert browser.text(f"{row} .why").startswith("yours")
        assert browser.find("#team") == [] and browser.find("#my-mounts") == []
        assert browser.find("#my-work a[href='/console/missions/new']"), "a client creates missions"
        assert browser.text("#my-broker-user") == "client1"


def test_an_admin_sets_use_cases_and_a_supervisor_sees_the_robots_read_only(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        for name, role in (
            ("admin1", UserRole.ADMIN),
            ("super1", UserRole.SUPERVISOR),
            ("client1", UserRole.CLIENT),
        ):
            console.user(name, role)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        _open_as(console, browser, "admin1", "/console/accounts")
        assert browser.text("#user-client1 .use-cases").startswith("every")
        browser.click("#user-client1 details.use-cases-edit summary")
        browser.click("#user-client1 input[name=scope][value=only]")
        browser.click("#user-client1 input[name=use_case][value=survey]")
        browser.click("#user-client1 form.use-cases-form button")
        browser.until(lambda: "client1's use cases are set." in browser.text(".notice"), "the use cases set")
        assert browser.text("#user-client1 .use-cases").startswith("survey")
        client = console.run(lambda: console.service.repositories.users.get_user("client1"))
        assert client is not None and client.use_cases == ("survey",)

        _open_as(console, browser, "super1", "/console/accounts")
        browser.until(lambda: browser.find("#read-only"), "the supervisor's view")
        assert browser.attributes("table.accounts tbody tr", "id") == ["user-explorer1"]
        assert browser.find("table.accounts form") == [] and browser.find("#create-user") == []
        assert browser.find("table.accounts details") == []


def test_the_roles_that_mount_nothing_see_their_own_work_and_broker_login(bus: Bus, browser: Browser) -> None:
    """A supervisor and a planner see the client's new mission waiting for their steps, an admin
    and a guest none (no step is theirs); the planner alone may create one; none has a mount list;
    each has a broker login whose password is shown once and can be renewed (the new one logs in,
    the old one no longer)."""
    roles = (UserRole.SUPERVISOR, UserRole.PLANNER, UserRole.ADMIN, UserRole.GUEST)
    with running_console(bus) as console:
        for role in roles:
            console.user_of(role)
        console.user("client1", UserRole.CLIENT)
        service = console.service

        async def setup() -> str:
            client = await service.repositories.users.get_user("client1")
            assert client is not None
            mission = await service.missions.create(client, "survey", "North yard", MissionPlan())
            return mission.mission_id

        mission_id = console.run(setup)
        state = console.run(lambda: service.missions.get_any(mission_id)).state
        for role in roles:
            name = role_user(role)
            _open_as(console, browser, name, "/console/")
            steps = machine_for("survey").steps_from(state)
            waiting = [step.target.value for step in steps if role in step.roles]
            assert bool(waiting) == (role in (UserRole.SUPERVISOR, UserRole.PLANNER)), (name, waiting)
            if waiting:
                assert browser.text(f"#my-mission-{mission_id} .why") == f"next for you: {', '.join(waiting)}"
            else:
                assert browser.find("#my-missions") == [] and browser.find("#no-missions"), name
            assert browser.find("#my-mounts") == [] and browser.find("#no-mounts") == [], name
            creates = bool(browser.find("#my-work a[href='/console/missions/new']"))
            assert creates == (role is UserRole.PLANNER), name
            assert bool(browser.find("#team")) == (role in WATCHERS), name
            assert browser.text("#my-broker-user") == name
            old_url = _broker_url(console, name)
            assert shown_once(browser, "#show-broker-password") == (
                service.accounts.broker_credentials(_user(console, name)).password,
                old_url,
            )
            browser.go(console.url("/console/"))
            _, new_url = shown_once(browser, "#new-broker-password")
            assert new_url == _broker_url(console, name) != old_url, name
            blocking_connection(new_url).close()
            with pytest.raises(pika.exceptions.ProbableAuthenticationError):
                blocking_connection(old_url)
