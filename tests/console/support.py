"""The console in a real browser: `fleetbus api`'s app served by uvicorn over real HTTP (on a
thread of the test process, so setup can use its services), driven by Debian's chromium,
headless, through Selenium and chromedriver.

Selenium rather than Playwright: Playwright's sync API keeps an asyncio loop running on the test's
thread, and the test helpers that set up the broker run their own (``asyncio.run``)."""

from __future__ import annotations

import asyncio
import logging
import os
import re
import shutil
import sys
import threading
import warnings
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import httpx
import uvicorn
from selenium import webdriver
from selenium.common.exceptions import StaleElementReferenceException, WebDriverException
from selenium.webdriver.chrome.service import Service as DriverService
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webelement import WebElement
from selenium.webdriver.support.select import Select
from sse_starlette.sse import AppStatus

from fleetbus.api.app import create_app
from fleetbus.api.console.session import CSRF_COOKIE, CSRF_HEADER, SESSION_COOKIE
from fleetbus.api.service import Service
from fleetbus.api.services.sessions import Origin
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.settings import Settings
from tests.api.server import free_port
from tests.support import Bus, wait_for

T = TypeVar("T")
PASSWORD = "correct horse battery"
#: The promise: what a robot publishes is on the operator's screen this soon, without a reload.
#: ``python -m bench.console`` measures it; a test only reports a slower update (a loaded CI
#: machine runs four browsers and brokers at once), as a warning in the run's summary.
LIVE_WITHIN_S = 2.0


def role_user(role: UserRole) -> str:
    """The name of the user a test makes for each role it sweeps (``guest*`` names are reserved)."""
    return f"user-{role.value}"


class SlowLiveUpdate(UserWarning):
    pass


def navigation(page: str) -> str:
    """The console's navigation in ``page``'s HTML (the header's links to the role's pages)."""
    found = re.search(r'<nav aria-label="console">(.*?)</nav>', page, re.S)
    assert found is not None, "a logged-in page has the navigation"
    return found.group(1)


def report_live(what: str, shown: float) -> None:
    """Say when a live update took longer than the promise; speed is the benchmark's to judge."""
    if shown >= LIVE_WITHIN_S:
        slow = SlowLiveUpdate(f"{what} took {shown:.2f} s (promised: {LIVE_WITHIN_S:g} s)")
        warnings.warn(slow, stacklevel=2)


def _replaced(error: WebDriverException) -> bool:
    """Whether ``error`` says the element was swapped out (by an htmx or SSE update) while read:
    chromedriver reports that as a stale reference or, mid-call, as this inspector error."""
    if isinstance(error, StaleElementReferenceException):
        return True
    return "does not belong to the document" in str(error)


def _executable(setting: str, *names: str) -> str:
    found = os.environ.get(setting) or next(filter(None, map(shutil.which, names)), None)
    if not found:
        raise RuntimeError(f"no {names[0]} found: run scripts/setup, or set {setting}")
    return found


def start_chromium() -> webdriver.Chrome:
    """Headless chromium (``FLEETBUS_CHROMIUM``, else ``chromium`` on PATH) through its chromedriver
    (``FLEETBUS_CHROMEDRIVER``, else ``chromedriver``); scripts/setup installs both."""
    options = webdriver.ChromeOptions()
    options.binary_location = _executable("FLEETBUS_CHROMIUM", "chromium", "chromium-browser")
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,900"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = DriverService(executable_path=_executable("FLEETBUS_CHROMEDRIVER", "chromedriver"))
    return webdriver.Chrome(options=options, service=service)


class Browser:
    """One headless chromium for a test process; each test gets it with no cookies and a blank page."""

    def __init__(self, driver: webdriver.Chrome) -> None:
        self.driver = driver

    def reset(self) -> None:
        self.driver.get("about:blank")
        self.driver.delete_all_cookies()
        # what the last test's pages logged once its server was gone (a live page's stream trying
        # to reconnect, until the blank page replaced it) is read and left out: each test's
        # console-error checks see only its own pages
        self.driver.get_log("browser")

    def go(self, url: str) -> None:
        self.driver.get(url)

    def find(self, css: str) -> list[WebElement]:
        return self.driver.find_elements(By.CSS_SELECTOR, css)

    def text(self, css: str) -> str:
        try:
            found = self.find(css)
            return found[0].text if found else ""
        except WebDriverException as error:
            if not _replaced(error):
                raise
            return self.text(css)

    def texts(self, css: str) -> list[str]:
        try:
            return [element.text for element in self.find(css)]
        except WebDriverException as error:
            if not _replaced(error):
                raise
            return self.texts(css)

    def attributes(self, css: str, name: str) -> list[str | None]:
        try:
            return [element.get_attribute(name) for element in self.find(css)]
        except WebDriverException as error:
            if not _replaced(error):
                raise
            return self.attributes(css, name)

    def until(self, condition: Callable[[], Any], what: str, timeout: float = 15) -> Any:
        """Wait (with a deadline) until ``condition()`` is true; fail saying ``what`` was awaited."""

        def holds() -> Any:
            try:
                return condition()
            except WebDriverException as error:
                if not _replaced(error):
                    raise
                return False

        try:
            return wait_for(holds, timeout=timeout, what=what, interval=0.05)
        except AssertionError as error:
            page = f"--- the page ({self.driver.current_url}) ---"
            raise AssertionError(f"{error}\n{page}\n{self._shown()}") from None

    def _shown(self, limit: int = 2000) -> str:
        """What the page shows, to say why a wait failed."""
        try:
            text = self.driver.find_element("css selector", "body").text
        except WebDriverException as error:
            return f"(unreadable: {error.msg})"
        return text if len(text) <= limit else text[:limit] + " …"

    def fill(self, css: str, value: str) -> None:
        try:
            element = self.find(css)[0]
            element.clear()
            element.send_keys(value)
        except WebDriverException as error:
            if not _replaced(error):
                raise
            self.fill(css, value)  # the new element gets the whole value

    def click(self, css: str) -> None:
        """Click the first match; one swapped out by a live update is found again and clicked
        (a stale element refuses the click before anything happens, so nothing is clicked twice)."""
        try:
            self.find(css)[0].click()
        except WebDriverException as error:
            if not _replaced(error):
                raise
            self.click(css)

    def console_errors(self) -> list[str]:
        return [entry["message"] for entry in self.driver.get_log("browser") if entry["level"] == "SEVERE"]


@dataclass
class Console:
    base: str
    service: Service
    bus: Bus
    loop: asyncio.AbstractEventLoop

    def run(self, work: Callable[[], Awaitable[T]]) -> T:
        """Run a coroutine on the server's event loop (where its store connection lives)."""
        return asyncio.run_coroutine_threadsafe(work(), self.loop).result(60)  # type: ignore[arg-type]

    def user(self, name: str, role: UserRole, kind: RobotKind | None = None) -> str:
        """A user made through the service (as an admin would), with its broker account."""
        self.bus.api.delete_user(name)  # broker users are broker-wide: one left by an aborted run
        self.run(lambda: self.service.accounts.create(name, PASSWORD, role, kind, by="test"))
        return name

    def user_of(self, role: UserRole) -> str:
        """A user of ``role``, named :func:`role_user`."""
        return self.user(role_user(role), role)

    def url(self, path: str) -> str:
        return self.base + path

    def log_in(self, browser: Browser, name: str, password: str = PASSWORD, base: str | None = None) -> None:
        """Log in as ``name`` at ``base`` (the console's own address unless a link's is given)."""
        browser.go(f"{base or self.base}/console/login")
        browser.fill("input[name=username]", name)
        browser.fill("input[name=password]", password)
        browser.click("form button[type=submit]")
        browser.until(lambda: name in browser.text(".who"), f"{name} logged in")

    def http_as(self, name: str) -> httpx.Client:
        """An HTTP client with a session of ``name`` (minted, as a login would: roles the console
        has no page for cannot log in to it)."""
        http = httpx.Client(base_url=self.base, timeout=30)
        http.cookies.set(SESSION_COOKIE, self.session(name))
        return http

    def session(self, name: str) -> str:
        """A new session's token for ``name`` (begun in the store, as a login does, without the
        password check or the console's refusal of roles it has no page for)."""
        return self.run(lambda: self.service.sessions.begin(name, Origin("127.0.0.1", "test"))).value

    def wait_live(self, browser: Browser) -> None:
        browser.until(
            lambda: browser.find("#live-status")[0].get_attribute("data-state") == "live", "the page live"
        )


@contextmanager
def running_console(bus: Bus, settings: Settings | None = None) -> Iterator[Console]:
    """``fleetbus api`` (the HTTP API and the console) on ``bus``, served over HTTP on a free
    port; the users it made are removed from the broker afterwards."""
    app = create_app(settings or bus.settings, bus.admin_url, bus.endpoint.management_url)
    port = free_port()
    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, log_level="warning", timeout_graceful_shutdown=5
    )
    server = uvicorn.Server(config)
    cut = _Cut()  # after Config, which configures uvicorn's loggers
    logging.getLogger("uvicorn.error").addHandler(cut)
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_until_complete, args=(server.serve(),), daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"

    def up() -> bool:
        if not thread.is_alive():
            raise AssertionError("the console's server stopped while starting")
        try:
            return httpx.get(f"{base}/health", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    wait_for(up, timeout=60, what="the console answering")
    console = Console(base, app.state.service, bus, loop)
    try:
        yield console
    finally:
        for user in console.run(console.service.repositories.users.users):
            bus.api.delete_user(user.name)
        # what uvicorn's signal handler does in `fleetbus api` (no handler in a thread): tell the
        # open live streams, which then end at once (api/console/live.py), and stop the server
        AppStatus.should_exit = True
        server.should_exit = True
        thread.join(30)
        AppStatus.should_exit = False  # for the next server of this process
        logging.getLogger("uvicorn.error").removeHandler(cut)
        left = asyncio.all_tasks(loop)
        if left:
            for task in left:
                task.cancel()

            async def settle() -> None:
                await asyncio.gather(*left, return_exceptions=True)

            loop.run_until_complete(settle())
        loop.close()
        if cut.messages and sys.exc_info()[0] is None:  # a test's own failure says more
            raise AssertionError(f"the console's server did not stop cleanly: {cut.messages}")


class _Cut(logging.Handler):
    """uvicorn's word that it cancelled what had not ended by its graceful shutdown timeout (an
    open page's stream that did not end when told)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if "graceful shutdown" in record.getMessage():
            self.messages.append(record.getMessage())


def choose_trails(browser: Browser, minutes: int) -> None:
    """Choose the live map's trails window (its select) and wait until its trails are loaded."""
    Select(browser.find("#trail-window")[0]).select_by_value(str(minutes))
    browser.until(lambda: browser.find("#map-view[data-trails=loaded]"), "the trails loaded")


def slide_map(browser: Browser, value: int) -> None:
    """Move the live map's time slider to ``value`` (of 1,000: now), as a user's drag does."""
    browser.driver.execute_script(
        "const s = document.getElementById('map-time'); s.value = arguments[0];"
        "s.dispatchEvent(new Event('input'));",
        value,
    )


def shown_once(browser: Browser, form: str) -> tuple[str, str]:
    """Press the button of ``form`` (one of the broker login's, on the dashboard or the account
    page); the password and URL the page then shows, after checking that a reload shows them no more."""
    browser.click(f"{form} button")
    browser.until(lambda: browser.text("#broker-password"), "the password shown")
    password, url = browser.text("#broker-password"), browser.text("#broker-url")
    browser.driver.refresh()
    browser.until(lambda: "not shown again" in browser.text("#not-shown"), "the reload without it")
    assert password not in browser.driver.page_source
    return password, url


@contextmanager
def http_session(console: Console, name: str) -> Iterator[httpx.Client]:
    """An HTTP client with ``name``'s console session (minted, no login form) and the CSRF header
    the console's htmx buttons send: for status codes and refusals without a browser."""
    with httpx.Client(base_url=console.base, timeout=30) as http:
        http.get("/console/login")  # the CSRF cookie
        http.cookies.set(SESSION_COOKIE, console.session(name))
        http.headers[CSRF_HEADER] = http.cookies[CSRF_COOKIE]
        yield http
