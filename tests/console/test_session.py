"""The console's session, CSRF, roles and headers over real HTTP (no browser needed to see them)."""

from __future__ import annotations

import httpx
import pytest

from fleetbus.api.console.headers import CONTENT_SECURITY_POLICY
from fleetbus.api.console.session import CSRF_COOKIE, SESSION_COOKIE
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.console.support import PASSWORD, Console, navigation, running_console
from tests.support import Bus


def log_in(console: Console, http: httpx.Client, name: str, password: str = PASSWORD) -> httpx.Response:
    form = http.get("/console/login")
    assert form.status_code == 200
    csrf = http.cookies[CSRF_COOKIE]
    return http.post("/console/login", data={"username": name, "password": password, "csrf": csrf})


@pytest.fixture
def console(bus: Bus):
    with running_console(bus) as running:
        yield running


def client(console: Console) -> httpx.Client:
    return httpx.Client(base_url=console.base, timeout=30)


def test_a_page_needs_a_session_and_the_session_cookie_is_locked_down(console: Console) -> None:
    console.user("oper1", UserRole.OPERATOR)
    with client(console) as http:
        assert http.get("/").headers["location"] == "/console/"
        away = http.get("/console/")
        assert away.status_code == 303 and away.headers["location"] == "/console/login?next=/console/"
        done = log_in(console, http, "oper1")
        assert done.status_code == 303 and done.headers["location"] == "/console/"
        cookie = next(c for c in done.headers.get_list("set-cookie") if c.startswith(SESSION_COOKIE))
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Max-Age=" in cookie
        page = http.get("/console/")
        assert page.status_code == 200 and "oper1" in page.text
        assert page.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
        assert (
            "'unsafe-inline'" not in CONTENT_SECURITY_POLICY
            and "script-src 'self'" in CONTENT_SECURITY_POLICY
        )
        assert page.headers["x-frame-options"] == "DENY"
        assert "<script>" not in page.text  # every script is a file of ours (no inline script)
        assert '<link rel="icon" href="/static/console/favicon.svg"' in page.text
        icon = http.get("/favicon.ico")  # where a browser looks without the link (no login needed)
        assert icon.status_code == 200 and icon.headers["content-type"] == "image/svg+xml"
        assert icon.content == http.get("/static/console/favicon.svg").content
        assert http.post("/console/logout", data={"csrf": http.cookies[CSRF_COOKIE]}).status_code == 303
        assert http.get("/console/").status_code == 303


def test_a_form_without_the_csrf_value_is_refused_before_anything_runs(console: Console) -> None:
    console.user("oper1", UserRole.OPERATOR)
    with client(console) as http:
        http.get("/console/login")
        refused = http.post("/console/login", data={"username": "oper1", "password": PASSWORD})
        assert refused.status_code == 403 and "CSRF" in refused.text
        forged = http.post(
            "/console/login", data={"username": "oper1", "password": PASSWORD, "csrf": "guessed"}
        )
        assert forged.status_code == 403
        assert SESSION_COOKIE not in http.cookies
        assert log_in(console, http, "oper1").status_code == 303


def test_wrong_passwords_meet_the_same_limit_as_the_api(bus: Bus) -> None:
    limited = bus.settings.updated(api_account_failures="2 per 1 minute")
    with running_console(bus, limited) as console, client(console) as http:
        console.user("oper1", UserRole.OPERATOR)
        for _ in range(2):
            wrong = log_in(console, http, "oper1", "not the password")
            assert wrong.status_code == 401 and "wrong user name or password" in wrong.text
        blocked = log_in(console, http, "oper1")  # the right password, but too many failures
        assert blocked.status_code == 429 and "too many failed logins" in blocked.text
        assert int(blocked.headers["retry-after"]) > 0
        api = httpx.post(
            f"{console.base}/auth/token", data={"username": "oper1", "password": PASSWORD}, timeout=30
        )
        assert api.status_code == 429  # one limit for the API and the console


def test_a_role_without_the_page_gets_403_and_no_link_to_it(console: Console) -> None:
    console.user("plan1", UserRole.PLANNER)
    console.user("robot1", UserRole.ROBOT)
    with client(console) as http:
        # a planner's session (minted: the pages a planner may open come with them), not the messages'
        http.cookies.set(SESSION_COOKIE, console.session("plan1"))
        refused = http.get("/console/messages")
        assert refused.status_code == 403 and "may not use the messages page" in refused.text
        assert 'href="/console/messages"' not in navigation(refused.text)
        assert http.get("/console/stream/dashboard").status_code == 403
    with client(console) as http:
        robot = log_in(console, http, "robot1")
        assert robot.status_code == 403 and "no page in the console" in robot.text
        assert SESSION_COOKIE not in http.cookies


def test_a_robot_refused_at_the_console_login_keeps_its_api_sessions(console: Console) -> None:
    """A robot has no page: its console login is refused before a session begins, so it does not
    take the place of one of its HTTP API sessions (a user keeps a bounded number)."""
    console.user("robot1", UserRole.ROBOT, RobotKind.EXPLORER)
    console.session("robot1")  # one of its API sessions
    sessions = console.service.sessions
    before = console.run(lambda: sessions.of("robot1"))
    with client(console) as http:
        refused = log_in(console, http, "robot1")
    assert refused.status_code == 403 and "role robot has no page in the console" in refused.text
    assert SESSION_COOKIE not in refused.cookies
    assert console.run(lambda: sessions.of("robot1")) == before
