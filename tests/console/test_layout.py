"""Every page of the console, as every role that may open it sees it, holds at a laptop's 1280x800
and at a tablet's 768-px width: no button, link or field cut off, hidden behind a scrollbar or off
the screen. And axe-core, an accessibility engine nobody on the project wrote, finds nothing wrong
in it (contrast, the names of controls, headings, landmarks: :mod:`tests.console.accessibility`).
The team has a mission in progress with a robot mounted and one free, so the pages show their
buttons (the mission's steps, Unmount, Mount with its robots) and their tables."""

from __future__ import annotations

from fleetbus.api.console.session import SESSION_COOKIE
from fleetbus.api.console.sitemap import ACCOUNT, ALERTS
from fleetbus.schemas.roles import UserRole
from tests.console.accessibility import violations
from tests.console.every_page import ROLES, page_paths, stage_team
from tests.console.layout import SIZES, overflows, reset_viewport, set_viewport
from tests.console.support import Browser, choose_trails, running_console, slide_map
from tests.support import Bus


def test_every_page_holds_at_1280x800_and_at_a_tablets_width_and_passes_axe_for_every_role(
    bus: Bus, browser: Browser
) -> None:
    problems: list[str] = []
    with running_console(bus) as console:
        stage_team(console)
        try:
            for role, name in ROLES.items():
                browser.reset()
                browser.go(console.url("/console/login"))
                if role is next(iter(ROLES)):
                    problems += violations(browser, "/console/login")
                browser.driver.add_cookie({"name": SESSION_COOKIE, "value": console.session(name)})
                sizes = list(SIZES)
                for path in page_paths(role):
                    browser.go(console.url(path))
                    assert name in browser.text(".who"), f"{path} as {role.value}: not its page"
                    problems += violations(browser, f"{path} as {role.value}")
                    if ALERTS.admits(role):  # checked with the banner in, as an operator sees it
                        assert browser.find("#alerts-banner li"), f"{path} as {role.value}: no alert shown"
                    for width, height in sizes:  # the page laid out again at each size, not reloaded
                        set_viewport(browser, width, height)
                        where = f"{path} as {role.value} at {width}x{height}"
                        problems += [f"{where}: {problem}" for problem in overflows(browser)]
                    sizes.reverse()  # the next page starts at the size this one ended at
        finally:
            reset_viewport(browser)
    assert problems == [], "\n".join(problems)


def test_the_mission_page_offers_the_robots_that_can_be_mounted_or_says_there_are_none(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        stage_team(console)
        operator = ROLES[UserRole.OPERATOR]
        console.log_in(browser, operator)
        browser.go(console.url("/console/missions/m-1"))
        options = browser.texts("#mount-form select[name=robot] option")
        assert options == ["explorer2"], "explorer1 is mounted already"
        browser.click("button[data-action=mount]")
        browser.until(lambda: browser.find("#mount-explorer2"), "explorer2 mounted")
        assert browser.find("#mount-form") == []
        assert "each of the team's 2 robots is mounted" in browser.text("#mount-none")


def _holds(browser: Browser, where: str) -> list[str]:
    """The page as it is now (not reloaded), laid out at each size, and what axe finds in it."""
    problems = violations(browser, where)
    for width, height in SIZES:
        set_viewport(browser, width, height)
        problems += [f"{where} at {width}x{height}: {problem}" for problem in overflows(browser)]
    return problems


def test_the_pages_a_button_opens_hold_and_pass_axe_too(bus: Bus, browser: Browser) -> None:
    """What no address opens again: a broker password shown once (the own, and one an administrator
    reset), and the live map with trails and its slider in the past."""
    problems: list[str] = []
    with running_console(bus) as console:
        stage_team(console)
        try:
            for role, opens, form in (
                (UserRole.OPERATOR, ACCOUNT.path, "#show-broker-password"),
                (UserRole.OPERATOR, ACCOUNT.path, "#new-broker-password"),
                (UserRole.ADMIN, "/console/accounts", "#user-explorer1 form.broker-password"),
            ):
                browser.reset()
                browser.go(console.url("/console/login"))
                browser.driver.add_cookie({"name": SESSION_COOKIE, "value": console.session(ROLES[role])})
                browser.go(console.url(opens))
                browser.click(f"{form} button")
                browser.until(lambda: browser.text("#broker-password"), f"{form}: the password shown")
                problems += _holds(browser, f"{form}'s password as {role.value}")
            browser.go(console.url("/console/map"))
            console.wait_live(browser)
            choose_trails(browser, 60)
            slide_map(browser, 500)
            browser.until(lambda: browser.text("#map-moment").endswith(" UTC"), "the map in the past")
            problems += _holds(browser, "the map with trails, in the past, as admin")
        finally:
            reset_viewport(browser)
    assert problems == [], "\n".join(problems)
