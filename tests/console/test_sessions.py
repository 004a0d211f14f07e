"""Console sessions end on the server, in a real browser, on the real broker and store: a copy of a
logged-out cookie opens nothing; an administrator ending a user's sessions shuts that user's open
console (its live page goes to the login form by itself) and API token out at once; a user's own
account page lists their sessions and ends them."""

from __future__ import annotations

from functools import partial

import httpx
import pika.exceptions
import pytest

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_FIELD, SESSION_COOKIE
from fleetbus.api.console.sitemap import CONSOLE_ROLES
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.roles import UserRole
from tests.console.support import PASSWORD, Browser, Console, role_user, running_console, shown_once
from tests.support import Bus

NEW_PASSWORD = "a new long password"


def _cookie(browser: Browser) -> str:
    cookie = browser.driver.get_cookie(SESSION_COOKIE)
    assert cookie is not None, "the browser holds a session cookie"
    return cookie["value"]


def _replayed(console: Console, cookie: str) -> httpx.Response:
    """The console's dashboard asked for with a copy of a session cookie."""
    with httpx.Client(base_url=console.base, timeout=30) as http:
        http.cookies.set(SESSION_COOKIE, cookie)
        return http.get("/console/")


def _token(console: Console, name: str, agent: str, password: str = PASSWORD) -> str:
    reply = httpx.post(
        f"{console.base}/auth/token",
        data={"username": name, "password": password},
        headers={"User-Agent": agent},
        timeout=30,
    )
    assert reply.status_code == 200, reply.text
    return reply.json()["access_token"]


def _api_status(console: Console, token: str) -> int:
    me = httpx.get(f"{console.base}/users/me", headers={"Authorization": f"Bearer {token}"}, timeout=30)
    return me.status_code


def _on_login_form(browser: Browser, what: str) -> None:
    browser.until(lambda: browser.find("input[name=username]"), what)


def test_logout_ends_the_session_and_an_admin_shuts_a_users_console_and_token_out(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        console.user("admin1", UserRole.ADMIN)
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        old = _cookie(browser)
        assert _replayed(console, old).status_code == 200
        browser.click("form.logout button")
        _on_login_form(browser, "the login form after logging out")
        replay = _replayed(console, old)
        assert replay.status_code == 303 and replay.headers["location"].startswith("/console/login")
        browser.driver.add_cookie({"name": SESSION_COOKIE, "value": old, "path": "/"})
        browser.go(console.url("/console/"))
        _on_login_form(browser, "the login form for the logged-out cookie put back")

        console.log_in(browser, "oper1")  # oper1's dashboard open and live, and a token of oper1's
        console.wait_live(browser)
        token = _token(console, "oper1", "script/1")
        with console.http_as("admin1") as admin:
            admin.get("/console/login")  # the CSRF cookie
            forged = admin.post("/console/accounts/oper1/sessions/end", data={CSRF_FIELD: "guessed"})
            assert forged.status_code == 403 and _api_status(console, token) == 200, "nothing ended"
            done = admin.post(
                "/console/accounts/oper1/sessions/end", data={CSRF_FIELD: admin.cookies[CSRF_COOKIE]}
            )
            assert done.status_code == 303
            shown = admin.get(done.headers["location"]).text
            assert "Every session of oper1 has ended" in shown
        assert _api_status(console, token) == 401
        # the open page's live stream is told, and the page goes to the login form by itself
        _on_login_form(browser, "oper1's open dashboard sent to the login form, with no reload by the test")


def test_the_own_account_page_lists_and_ends_sessions_and_changes_the_password(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        script = _token(console, "oper1", "robot-script/7")
        browser.click("a.who")
        browser.until(lambda: len(browser.find("table.sessions tbody tr")) == 2, "two sessions listed")
        assert browser.text("#account-name") == "oper1" and browser.text("#account-role") == "operator"
        rows = browser.texts("table.sessions tbody tr")
        assert "robot-script/7" in rows[0] and "127.0.0.1" in rows[0]
        assert "this one" in rows[1] and "robot-script/7" not in rows[1]

        browser.click("table.sessions tbody tr:first-child form.end-session button")
        browser.until(lambda: "That session has ended" in browser.text(".notice"), "the session ended")
        assert len(browser.find("table.sessions tbody tr")) == 1
        assert _api_status(console, script) == 401

        other = _token(console, "oper1", "robot-script/8")
        browser.go(console.url("/console/account"))
        browser.fill("#change-password input[name=current_password]", "not the password")
        browser.fill("#change-password input[name=new_password]", NEW_PASSWORD)
        browser.click("#change-password button")
        browser.until(lambda: browser.text("#problem") == "the current password is wrong", "the refusal")
        assert _api_status(console, other) == 200, "a refused change ends nothing"
        browser.fill("#change-password input[name=current_password]", PASSWORD)
        browser.fill("#change-password input[name=new_password]", NEW_PASSWORD)
        browser.click("#change-password button")
        browser.until(lambda: "Your password is changed" in browser.text(".notice"), "the password changed")
        assert _api_status(console, other) == 401
        assert _api_status(console, _token(console, "oper1", "x/1", NEW_PASSWORD)) == 200

        browser.go(console.url("/console/account"))
        mine = _cookie(browser)
        browser.click("table.sessions tr.current form.end-session button")
        _on_login_form(browser, "the login form after ending this browser's own session")
        assert _replayed(console, mine).status_code == 303


def test_every_role_sees_its_account_renews_its_broker_password_and_ends_its_sessions(
    bus: Bus, browser: Browser
) -> None:
    """The own account page for each role that logs in to the console, on one console: its name and
    role, a token's session listed and ended, a new broker password (shown once; the old one no
    longer logs in), a password change, and logging out by ending this browser's session."""
    with running_console(bus) as console:
        for role in CONSOLE_ROLES:
            console.user_of(role)
        for role in sorted(CONSOLE_ROLES, key=lambda r: r.value):
            name = role_user(role)
            browser.reset()
            console.log_in(browser, name)
            script = _token(console, name, "robot-script/7")
            browser.click("a.who")
            browser.until(lambda: len(browser.find("table.sessions tbody tr")) == 2, f"{name}'s two sessions")
            assert (browser.text("#account-name"), browser.text("#account-role")) == (name, role.value)
            browser.click("table.sessions tbody tr:not(.current) form.end-session button")
            ended = lambda: "That session has ended" in browser.text(".notice")  # noqa: E731
            browser.until(ended, f"{name}'s token ended")
            assert _api_status(console, script) == 401

            user = console.run(partial(console.service.repositories.users.get_user, name))
            assert user is not None
            old_url = console.service.accounts.broker_credentials(user).amqp_url
            assert old_url not in browser.driver.page_source
            _, new_url = shown_once(browser, "#new-broker-password")
            assert new_url != old_url
            blocking_connection(new_url).close()
            with pytest.raises(pika.exceptions.ProbableAuthenticationError):
                blocking_connection(old_url)

            browser.go(console.url("/console/account"))
            browser.fill("#change-password input[name=current_password]", PASSWORD)
            browser.fill("#change-password input[name=new_password]", NEW_PASSWORD)
            browser.click("#change-password button")
            browser.until(lambda: "Your password is changed" in browser.text(".notice"), f"{name}'s password")
            mine = _cookie(browser)
            browser.click("table.sessions tr.current form.end-session button")
            _on_login_form(browser, f"{name} logged out by ending this browser's session")
            assert _replayed(console, mine).status_code == 303
