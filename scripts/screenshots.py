"""Screenshots of every console page, for the documentation: ``docs/images/console/<page>.png``.

    bash scripts/screenshots            # scripts/setup first; a minute or two

A private demo on this checkout's broker node: `fleetbus demo`'s team (an explorer, two wardens
and a guide: hazards held until the wardens localised, then announced, claimed and cleared; a
map; beacons) in a virtual host and a store of its own (a temporary folder), then a few steps
more: the robots connected again with a status each, a message the worker refuses, hazards left
claimed and reached, two missions (one in progress, with depth soundings, a discussion and the
explorer mounted by the operator, who is checked in), a user of each role (the client limited to
hazard responses); the worker and the recorder run meanwhile. The console (`fleetbus api`'s app)
is served on that store; headless chromium (as in the browser tests) logs in as an administrator
and saves the login form, each page of ``sitemap.PAGES`` (pages added later are included), the
map with the last hour's trails and its slider a quarter back (``map-past.png``: the team's paths
of the last 40 minutes are staged), the own account page (``account.png``) and the survey's page
(``mission.png``), then the operator's dashboard (``dashboard-operator.png``: its
own work), then, as the planner, the new mission form with a plan drawn on the map and its
summary; 1280 pixels wide and up to 1,600 tall.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

from rich.console import Console

from fleetbus.api.console.sitemap import ACCOUNT, DASHBOARD, MAP, PAGES
from fleetbus.broker.accounts import Role, with_vhost
from fleetbus.broker.management import ManagementAPI
from fleetbus.cli.context import endpoint as resolved_broker
from fleetbus.schemas.missions import MissionPlan, MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import EventType, RobotKind
from fleetbus.settings import load_settings
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.hazards import DEFAULT_MISSION
from fleetbus_dev.demo import DEMO_VHOST, EXPLORER, TEAM, WARDENS, demo_status, run_demo
from tests.console.support import Browser, choose_trails, running_console, slide_map, start_chromium
from tests.console.support import Console as RunningConsole
from tests.support import Bus, wait_for

ROOT = Path(__file__).resolve().parent.parent
WIDTH = 1280
MAX_HEIGHT = 1600
ADMIN = f"demo-{UserRole.ADMIN.value}"
SURVEY = {
    "geofence": {"polygon": [{"x": 0, "y": 0}, {"x": 40, "y": 0}, {"x": 40, "y": 25}, {"x": 0, "y": 25}]},
    "points_of_interest": [{"name": "lab", "x": 8, "y": 3}, {"name": "stairs", "x": 4, "y": 9}],
    "itinerary": [{"action": "sweep the lab", "point_of_interest": "lab"}],
}
console = Console()


def back_online(bus: Bus) -> None:
    """The demo's robots connected again (run_demo removes their accounts when it ends), each with
    a status, and one message the worker must refuse (a dead letter)."""
    for i, (name, kind) in enumerate(TEAM):
        account = bus.add(name, Role.ROBOT, kind)
        bus.robot(account).publish(EventType.STATUS, demo_status(10 + 25 * i))
        if kind is RobotKind.EXPLORER:
            bus.publish_raw(account, f"{name}.status", b'{"robot_id": "not a valid event"}')
    wait_for(lambda: bus.dead_letters(), what="the refused message dead-lettered")


def soundings(mission_id: str, count: int = 800) -> list[EventRecord]:
    """Depth soundings the explorer took over the survey's area, recorded under the mission."""
    at = datetime.now(timezone.utc)
    records = []
    for i in range(count):
        x, y = (i * 7919 % 997) / 997 * 40, (i * 104729 % 991) / 991 * 25
        depth = 2 + 6 * x / 40 + 2 * math.sin(y / 4)
        body = {"quantity": "depth", "value": round(depth, 2), "unit": "m", "pose": {"x": x, "y": y}}
        records.append(
            EventRecord(
                EXPLORER, "20261128T000000000Z-5ca1ab1e", i, EventType.MEASUREMENT.value, f"sounding-{i}",
                at, at, body, EXPLORER, f"{EXPLORER}.events", f"{EXPLORER}.measurement", mission_id,
            )
        )  # fmt: skip
    return records


def paths(now: datetime) -> list[EventRecord]:
    """Where each robot of the team went over the last 40 minutes (a localisation a minute, ending
    at the pose of its status), for the map's trails and its time slider."""
    records = []
    for i, (name, _) in enumerate(TEAM):
        end = demo_status(10 + 25 * i)["pose"]["x"]
        for step in range(40):
            x, y = end - 8 + 8 * step / 39, 1 + 3 * math.sin(step / 6 + i)
            at = now - timedelta(minutes=40 - step)
            body = {"localised": True, "pose": {"x": round(x, 2), "y": round(y, 2)}}
            records.append(
                EventRecord(
                    name, "20261128T000000000Z-0a7b0a7b", step, EventType.LOCALISATION.value,
                    f"path-{name}-{step}", at, at, body, name, f"{name}.events", f"{name}.localisation",
                )
            )  # fmt: skip
    return records


def stage(running: RunningConsole) -> str:
    """Beyond the demo: a user of each role, two missions, hazards left claimed and reached; the
    survey's soundings and discussion. The survey's id."""
    people = [role for role in UserRole if role not in (UserRole.ROBOT, UserRole.INACTIVE)]
    users = {role: running.user(f"demo-{role.value}", role) for role in people}
    service = running.service
    now = datetime.now(timezone.utc)

    async def steps() -> str:
        accounts = service.repositories.users
        planner = await accounts.get_user(users[UserRole.PLANNER])
        supervisor = await accounts.get_user(users[UserRole.SUPERVISOR])
        client = await accounts.get_user(users[UserRole.CLIENT])
        assert planner and supervisor and client
        survey = await service.missions.create(
            planner, "survey", "Survey of building C", MissionPlan.model_validate(SURVEY)
        )
        await service.missions.transition(
            supervisor, survey.mission_id, MissionState.IN_PROGRESS, "team ready"
        )
        await service.missions.create(client, "hazard-response", "Gas leak, east wing", MissionPlan())
        # the client may create hazard responses only (the accounts page shows whose use cases are limited)
        await service.accounts.set_use_cases(client.name, ["hazard-response"], by=ADMIN)
        await service.repositories.events.write_events(soundings(survey.mission_id))
        await service.repositories.events.write_events(paths(now))
        operator = await accounts.get_user(users[UserRole.OPERATOR])
        assert operator
        await service.channels.mount(operator, EXPLORER, survey.mission_id)  # the soundings' robot
        await service.channels.check_in(operator, survey.mission_id)
        discussion = service.mission_comments
        for who, text in (
            (planner, "Sweep the lab first, then the stairs."),
            (operator, "Soundings of the whole floor are in; the east side is deeper."),
            (supervisor, "Good. Keep away from the stairs until they are checked."),
        ):
            await discussion.add(who, survey.mission_id, text)
        hazards = service.repositories.hazards
        await hazards.claim(DEFAULT_MISSION, 2, WARDENS[0], now)
        await hazards.claim(DEFAULT_MISSION, 3, WARDENS[1], now)
        await hazards.mark_reached(DEFAULT_MISSION, 3, WARDENS[1], now)
        return survey.mission_id

    return running.run(steps)


def shoot(browser: Browser, path: Path, width: int) -> None:
    """The page ``width`` pixels wide, as tall as it is up to ``MAX_HEIGHT`` (a long list is cut)."""
    browser.driver.set_window_size(width, 600)
    height, frame = browser.driver.execute_script(
        "return [document.documentElement.scrollHeight, window.outerHeight - window.innerHeight]"
    )
    browser.driver.set_window_size(width, max(600, min(int(height), MAX_HEIGHT)) + int(frame))
    path.write_bytes(browser.driver.get_screenshot_as_png())
    console.print(f"wrote {path}")


def settled(browser: Browser) -> None:
    """Until the dashboard shows what the broker's management API tells a few seconds late: the
    robots connected, the worker and the recorder consuming."""
    consuming = (
        "return ['fleetbus.ingest.events', 'fleetbus.recorder'].every((name) => {"
        "  const row = document.getElementById('queue-' + name);"
        "  return row && !row.classList.contains('idle') })"
    )
    browser.until(
        lambda: (
            browser.texts("#team td.connected") == ["yes"] * len(TEAM)
            and browser.driver.execute_script(consuming)
        ),
        "the robots connected and the worker and recorder consuming, on the dashboard",
        timeout=60,
    )


def my_work(running: RunningConsole, browser: Browser, out: Path, width: int) -> None:
    """The operator's dashboard: its own work (the survey, the robot it mounted, its check-in)."""
    browser.reset()
    running.log_in(browser, f"demo-{UserRole.OPERATOR.value}")
    running.wait_live(browser)
    settled(browser)
    shoot(browser, out / "dashboard-operator.png", width)


def new_mission(running: RunningConsole, browser: Browser, out: Path, width: int) -> None:
    """A new mission's summary, then its form (back from the summary: the map fitted to the plan),
    as the demo's planner sees them."""
    browser.reset()
    running.log_in(browser, f"demo-{UserRole.PLANNER.value}")
    browser.go(running.url("/console/missions/new"))
    browser.fill("input[name=title]", "Sweep of the east wing")
    browser.fill("textarea[name=geofence]", "2 2\n30 2\n30 20\n2 20")
    browser.fill("textarea[name=points_of_interest]", "lab, 8, 3, gas cylinders\nstairs, 4, 9")
    ready = (
        "const v = document.getElementById('plan-map'), image = document.getElementById('plan-image');"
        "return !!(v && v.dataset.ready) && (!image || image.complete)"
    )
    browser.click("button[data-action=summary]")
    browser.until(
        lambda: browser.find("#confirm-form") and browser.driver.execute_script(ready), "the summary's map"
    )
    shoot(browser, out / "missions-summary.png", width)
    browser.click("button[data-action=edit]")  # back: the form's map fitted to the plan
    browser.until(
        lambda: browser.find("form.mission-form") and browser.driver.execute_script(ready),
        "the plan drawn on the form's map",
    )
    shoot(browser, out / "missions-new.png", width)


def screenshots(running: RunningConsole, out: Path, width: int, mission_id: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    browser = Browser(start_chromium())
    try:
        browser.go(running.url("/console/login"))
        shoot(browser, out / "login.png", width)
        running.log_in(browser, ADMIN)
        for page in PAGES:
            browser.go(running.url(page.path))
            if browser.find("main[data-stream]"):
                running.wait_live(browser)
                # two ticks of the feed: the page's first updates are in (its own stream counted)
                time.sleep(2 * running.service.settings.console_tick_s)
            if page is DASHBOARD:
                settled(browser)
            shoot(browser, out / f"{page.name}.png", width)
        # the map's trails, and the team as it stood 15 minutes ago
        browser.go(running.url(MAP.path))
        running.wait_live(browser)
        choose_trails(browser, 60)
        slide_map(browser, 750)
        browser.until(lambda: browser.find("[data-past]"), "the team as it stood then")
        shoot(browser, out / "map-past.png", width)
        # the user's own account (not in the navigation: the name in the header links to it)
        browser.go(running.url(ACCOUNT.path))
        shoot(browser, out / "account.png", width)
        # a mission's page (not in the navigation): its sensor data mapped, its discussion
        browser.go(running.url(f"/console/missions/{mission_id}"))
        running.wait_live(browser)
        browser.until(lambda: browser.attributes("#mission-map", "data-loaded-ms")[0], "the soundings mapped")
        shoot(browser, out / "mission.png", width)
        my_work(running, browser, out, width)
        new_mission(running, browser, out, width)
    finally:
        browser.driver.quit()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "docs" / "images" / "console", help="where they go"
    )
    parser.add_argument("--width", type=int, default=WIDTH, help="the window's width in pixels")
    args = parser.parse_args()
    settings = load_settings()
    endpoint = resolved_broker()  # as `fleetbus demo` finds it; a clean error when there is none
    with tempfile.TemporaryDirectory(prefix="fleetbus-screenshots-") as folder:
        demo = settings.updated(data_dir=Path(folder), mongodb_url=None)
        console.print("running the demo team")
        run_demo(demo, endpoint, console)
        # the store and virtual host run_demo used and left
        store = demo.updated(
            data_dir=Path(folder) / "demo",
            amqp_url=with_vhost(endpoint.amqp_url, DEMO_VHOST),
            management_url=endpoint.management_url,
        )
        with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
            bus = Bus(endpoint, api, DEMO_VHOST, store)
            try:
                with bus.worker(), bus.recorder(), running_console(bus) as running:
                    back_online(bus)
                    survey = stage(running)
                    screenshots(running, args.out, args.width, survey)
            finally:
                bus.close_robots()
                bus.remove_accounts()
                api.delete_vhost(DEMO_VHOST)


if __name__ == "__main__":
    main()
