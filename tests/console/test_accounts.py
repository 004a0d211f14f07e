"""The accounts page in a real browser, on the real broker and store: an administrator creates a
user who then logs in, disables it, and gives a robot a new broker password, shown once."""

from __future__ import annotations

import logging
from urllib.parse import urlsplit

import httpx
import pika
import pika.exceptions
import pytest
from selenium.webdriver.support.ui import Select

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_FIELD, SESSION_COOKIE
from fleetbus.api.services.security import password_problem
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import PASSWORD, Browser, Console, running_console
from tests.support import Bus

#: The test's own browser driver logs what it reads from the page; the service's logs are the point.
TEST_SIDE_LOGGERS = ("selenium", "urllib3")


def _create(browser: Browser, name: str, role: UserRole, password: str) -> None:
    browser.fill("#create-user input[name=name]", name)
    Select(browser.find("#create-user select[name=role]")[0]).select_by_value(role.value)
    browser.fill("#create-user input[name=password]", password)
    browser.click("#create-user button[type=submit]")


def _log_out(browser: Browser) -> None:
    browser.click("form.logout button")
    browser.until(lambda: browser.find("input[name=username]"), "the login form")


def _name_problem(name: str) -> str:
    """The service's own words for a bad name (so this test states no rule of its own)."""
    with pytest.raises(ValueError) as refused:
        validate_name(name)
    return str(refused.value)


def test_an_admin_creates_a_user_who_logs_in_and_disabling_it_stops_its_login(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        console.user("admin1", UserRole.ADMIN)
        console.log_in(browser, "admin1")
        browser.go(console.url("/console/accounts"))

        _create(browser, "Bad.Name", UserRole.OPERATOR, PASSWORD)
        bad_name = _name_problem("Bad.Name")
        browser.until(lambda: browser.text("#problem") == bad_name, "the service's refusal of the name")
        assert browser.find("#create-user input[name=name]")[0].get_attribute("value") == "Bad.Name"
        assert browser.find("#create-user input[name=password]")[0].get_attribute("value") == ""
        _create(browser, "newop1", UserRole.OPERATOR, "short")
        short = password_problem("short")
        browser.until(lambda: browser.text("#problem") == short, "the service's refusal of the password")

        _create(browser, "newop1", UserRole.OPERATOR, PASSWORD)
        browser.until(lambda: "User newop1 created." in browser.text(".notice"), "the user created")
        assert browser.text("#user-newop1 .role") == "operator"
        assert "admin1" in browser.text("#user-newop1")  # created by
        _log_out(browser)
        console.log_in(browser, "newop1")  # the new user's own login works
        _log_out(browser)

        console.log_in(browser, "admin1")
        browser.go(console.url("/console/accounts"))
        browser.click("#user-newop1 form.disable button")
        browser.until(lambda: browser.text("#user-newop1 .role") == "inactive", "the user disabled")
        assert browser.text("#user-newop1 .active") == "no"
        _log_out(browser)
        browser.fill("input[name=username]", "newop1")
        browser.fill("input[name=password]", PASSWORD)
        browser.click("form button[type=submit]")
        browser.until(lambda: "inactive" in browser.text(".problem"), "the disabled user's login refused")
        assert browser.find(".who") == []


def test_a_new_broker_password_is_shown_once_works_on_the_broker_and_is_in_no_log(
    bus: Bus, browser: Browser, caplog: pytest.LogCaptureFixture
) -> None:
    with running_console(bus) as console:
        console.user("admin1", UserRole.ADMIN)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        old_url = _broker_url(console, "explorer1")
        console.log_in(browser, "admin1")
        browser.go(console.url("/console/accounts"))
        caplog.set_level(logging.DEBUG)

        browser.click("#user-explorer1 form.broker-password button")
        browser.until(lambda: browser.text("#broker-password"), "the new password")
        password, url = browser.text("#broker-password"), browser.text("#broker-url")
        assert "shown once" in browser.text("#shown-once")
        browser.driver.refresh()
        browser.until(lambda: "not shown again" in browser.text("#not-shown"), "the reload without it")
        assert password not in browser.driver.page_source

        server_side = [r for r in caplog.records if not r.name.startswith(TEST_SIDE_LOGGERS)]
        assert any("broker password reset by admin1" in r.getMessage() for r in server_side)
        assert not [r.getMessage() for r in server_side if password in r.getMessage()], "never in a log"
        assert url == _broker_url(console, "explorer1") and password in url
        connection = blocking_connection(url)  # the new password logs in
        connection.channel().queue_declare("explorer1.inbox", passive=True)  # with its permissions
        connection.close()
        with pytest.raises(pika.exceptions.ProbableAuthenticationError):
            blocking_connection(old_url)


def test_the_page_with_the_new_password_is_never_stored_by_a_cache(bus: Bus) -> None:
    with running_console(bus) as console, httpx.Client(base_url=console.base, timeout=30) as http:
        console.user("admin1", UserRole.ADMIN)
        console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        http.get("/console/login")
        http.cookies.set(SESSION_COOKIE, console.session("admin1"))
        csrf = {CSRF_FIELD: http.cookies[CSRF_COOKIE]}
        reset = http.post("/console/accounts/explorer1/broker-password", data=csrf)
        assert reset.status_code == 303 and reset.headers["cache-control"] == "no-store"
        shown = http.get(reset.headers["location"])
        password = urlsplit(_broker_url(console, "explorer1")).password
        assert password
        assert shown.status_code == 200 and shown.headers["cache-control"] == "no-store"
        assert password in shown.text and "shown once" in shown.text
        again = http.get(reset.headers["location"])
        assert again.headers["cache-control"] == "no-store" and password not in again.text


def _broker_url(console: Console, name: str) -> str:
    user = console.run(lambda: console.service.repositories.users.get_user(name))
    assert user is not None
    return console.service.accounts.broker_credentials(user).amqp_url
