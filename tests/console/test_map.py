"""The live map in a real browser, on the real broker, worker and store; its image and frame."""

from __future__ import annotations

import io
import time
from datetime import datetime, timedelta, timezone
from typing import Any

import httpx
from PIL import Image
from selenium.webdriver.support.select import Select

from fleetbus.api.console.latest import Latest
from fleetbus.api.console.map_image import Frame, png_of
from fleetbus.api.console.pages.live_map import MapView
from fleetbus.broker.accounts import Role
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventRecord
from fleetbus.workers.store.beacons import Beacon
from fleetbus.workers.store.hazards import NewHazard
from fleetbus.workers.store.maps import MapVersion
from tests.console.support import (
    Browser,
    Console,
    http_session,
    navigation,
    report_live,
    role_user,
    running_console,
)
from tests.factories import hazard, small_map, status
from tests.support import Bus, wait_for

#: small_map's world: 64 x 48 pixels of 0.11 m from (2.1, 3.5), so x 2.1 to 9.14, y 3.5 to 8.78.
INSIDE = {"x": 5.0, "y": 6.0}


def at(body: dict[str, Any], x: float, y: float) -> dict[str, Any]:
    return {**body, "pose": {"x": x, "y": y}}


def natural_width(browser: Browser) -> int:
    return browser.driver.execute_script(
        "const image = document.getElementById('map-image');"
        "return image && image.complete ? image.naturalWidth : 0"
    )


def where(browser: Browser, mark: str) -> tuple[str | None, str | None]:
    """Where the page puts the mark ``mark`` (its world x and y, as the server rendered them)."""
    found = browser.find(f"#{mark}")
    return (found[0].get_attribute("data-x"), found[0].get_attribute("data-y")) if found else (None, None)


def drawn(browser: Browser, mark: str) -> bool:
    """Whether the map draws the mark ``mark`` (a Leaflet marker)."""
    return bool(browser.find(f".leaflet-marker-icon[data-mark='{mark}']"))


def stored_maps(bus: Bus, count: int) -> None:
    wait_for(
        lambda: len(bus.with_store(lambda store: store.maps.map_versions())) == count,
        what=f"{count} map versions stored",
    )


def open_map(console: Console, browser: Browser, query: str = "", role: UserRole = UserRole.OPERATOR) -> None:
    """The live map, live, as a new user of ``role`` (``oper1`` for an operator)."""
    name = "oper1" if role is UserRole.OPERATOR else role_user(role)
    console.user(name, role)
    console.log_in(browser, name)
    browser.go(console.url("/console/map" + query))
    console.wait_live(browser)


def test_a_published_hazard_appears_on_the_map_live_with_its_id(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    guide = bus.robot(bus.add("guide1", Role.ROBOT, RobotKind.GUIDE))
    bus.with_store(lambda store: store.beacons.put_beacons([Beacon("b1", 8.0, 7.5, "room 101")]))
    with bus.worker(), running_console(bus) as console:
        # first events through the whole chain (the worker is up): a map, and where the explorer is
        explorer.publish("map", small_map())
        explorer.publish("status", at(status(80.0), 4.0, 5.0))
        stored_maps(bus, 1)
        open_map(console, browser)
        browser.until(lambda: natural_width(browser) == 64, "the map's image loaded")
        browser.until(lambda: drawn(browser, "mark-robot-explorer1"), "the explorer's last pose")
        assert where(browser, "mark-robot-explorer1") == ("4.000", "5.000")
        browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")
        # what the stream puts in the list of provisional marks, noted as it comes
        browser.driver.execute_script(
            "window.__news = []; new MutationObserver((changes) => changes.forEach((c) =>"
            " c.addedNodes.forEach((n) => window.__news.push(n.id))))"
            ".observe(document.getElementById('map-news'), {childList: true})"
        )

        published = time.monotonic()
        event = explorer.publish("hazard", at(hazard(0, description="Gas leak"), INSIDE["x"], INSIDE["y"]))
        browser.until(lambda: drawn(browser, "mark-hazard-default-1"), "the hazard's marker")
        shown = time.monotonic() - published
        # its provisional mark came first, from its event, and went once the hazard was registered
        key = f"{event.robot_id}-{event.epoch}-{event.seq}"
        assert browser.driver.execute_script("return window.__news") == [f"mark-new-{key}"]
        browser.until(lambda: not browser.find("#map-news li"), "the provisional mark dropped")
        assert not browser.find(f"[data-mark='mark-new-{key}']"), "no marker of it left"
        marker = browser.find(".leaflet-marker-icon[data-mark='mark-hazard-default-1']")[0]
        assert marker.text == "1", "its id"
        assert where(browser, "mark-hazard-default-1") == ("5.000", "6.000"), "where the robot saw it"
        assert "state-held" in marker.get_attribute("class")
        report_live("the hazard on the map", shown)
        assert "Gas leak" in browser.text("#map-hazard-default-1")

        explorer.publish("status", at(status(79.0), 6.5, 4.0))  # the explorer moves
        browser.until(
            lambda: where(browser, "mark-robot-explorer1") == ("6.500", "4.000"), "the explorer's new pose"
        )
        browser.until(
            lambda: (
                browser.attributes(".leaflet-marker-icon[data-mark='mark-robot-explorer1']", "data-x")
                == ["6.500"]
            ),
            "the explorer's marker moved",
        )
        guide.publish("beacon", {"beacon_id": "b1", "rssi": -60, "pose": {"x": 7.5, "y": 7.0}})
        browser.until(
            lambda: (
                "stranded"
                in browser.find(".leaflet-marker-icon[data-mark='mark-beacon-b1']")[0].get_attribute("class")
            ),
            "people likely stranded at beacon b1",
        )
        assert "room 101" in browser.text("#map-stranded-b1")
        assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"
        assert browser.console_errors() == []


def test_an_older_map_version_can_be_chosen(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        explorer.publish("map", small_map(64, 48))
        explorer.publish("map", small_map(80, 60))
        explorer.publish("hazard", at(hazard(0), INSIDE["x"], INSIDE["y"]))
        stored_maps(bus, 2)
        open_map(console, browser)
        browser.until(lambda: natural_width(browser) == 80, "the newest version shown")
        assert browser.find("#map-image")[0].get_attribute("src").endswith("/console/map/2.png")
        browser.until(lambda: drawn(browser, "mark-hazard-default-1"), "the hazard's marker")

        Select(browser.find("select[name=version]")[0]).select_by_value("1")
        browser.until(lambda: natural_width(browser) == 64, "version 1 shown")
        assert browser.find("#map-image")[0].get_attribute("src").endswith("/console/map/1.png")
        assert browser.text(".map-caption").startswith("Version 1 from explorer1")
        assert browser.driver.current_url.endswith("/console/map?version=1"), "the address says which"
        assert drawn(browser, "mark-hazard-default-1"), "the markers stay over the other version"
        browser.go(console.url("/console/map?version=1"))
        browser.until(lambda: natural_width(browser) == 64, "version 1 from its address")


def test_the_map_is_refused_to_planners_and_clients(bus: Bus) -> None:
    """Authors see only the newest version, on the new mission form; the watchers every one."""
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        explorer.publish("map", small_map())
        explorer.publish("map", small_map(80, 60))
        stored_maps(bus, 2)
        paths = (
            "/console/map",
            "/console/map/frame?version=1",
            "/console/map/1.png",
            "/console/map/trails",
            "/console/stream/map",
        )
        for name, role in (("plan1", UserRole.PLANNER), ("client1", UserRole.CLIENT)):
            console.user(name, role)
            with console.http_as(name) as http:
                for path in paths:
                    assert http.get(path).status_code == 403, (name, path)
                assert "may not use the live map page" in http.get("/console/map").text
                newest = http.get("/console/missions/new/map/2.png")
                assert newest.status_code == 200 and newest.headers["content-type"] == "image/png"
                assert Image.open(io.BytesIO(newest.content)).size == (80, 60)
                older = http.get("/console/missions/new/map/1.png")
                assert older.status_code == 403 and "the newest map version only (2)" in older.text, name
                assert http.get("/console/missions/new/map/7.png").status_code == 404
        console.user("oper1", UserRole.OPERATOR)
        with console.http_as("oper1") as http:
            png = http.get("/console/map/1.png")
            assert png.status_code == 200 and png.headers["content-type"] == "image/png"
            assert Image.open(io.BytesIO(png.content)).size == (64, 48)
            missing = http.get("/console/map/7.png")
            assert missing.status_code == 404 and "no map version 7" in missing.text
            assert 'href="/console/map"' in navigation(http.get("/console/map").text)
        with console.http_as("plan1") as http:
            assert 'href="/console/map"' not in navigation(http.get("/console/map").text)


def test_every_pgm_a_robot_may_send_is_drawn_and_large_ones_scaled_down() -> None:
    plain = b"P2\n# a comment\n3 2\n15\n0 5 10\n15 15 0\n"
    sixteen = b"P5\n2 1\n65535\n" + (0).to_bytes(2, "big") + (65535).to_bytes(2, "big")
    assert Image.open(io.BytesIO(png_of(plain, 2048))).getpixel((2, 0)) == 170
    assert Image.open(io.BytesIO(png_of(sixteen, 2048))).tobytes() == bytes([0, 255])
    large = b"P5\n3000 1000\n255\n" + bytes(3000 * 1000)
    assert Image.open(io.BytesIO(png_of(large, 600))).size == (600, 200)


def test_the_frame_puts_the_lower_left_pixel_at_the_maps_origin() -> None:
    metadata = {"resolution": 0.5, "origin": [-3.0, 2.0, 0.0]}
    version = MapVersion(1, "explorer1", "e", 0, metadata, None, 0, "", 0, 1)  # type: ignore[arg-type]
    frame = Frame(version, width=40, height=20)
    # x from -3 to 17; y from 2 to 12
    assert frame.bounds == "-3 2 17 12"


def test_a_session_less_request_for_the_image_is_sent_to_log_in(bus: Bus) -> None:
    with running_console(bus) as console:
        away = httpx.get(console.url("/console/map/1.png"), timeout=30)
        assert away.status_code == 303 and away.headers["location"].startswith("/console/login")


def test_the_map_and_the_dashboard_draw_the_newest_hazards_and_count_the_rest(bus: Bus) -> None:
    settings = bus.settings.updated(console_map_hazards=2)
    with running_console(bus, settings) as console:
        console.user("oper1", UserRole.OPERATOR)
        received = datetime.now(timezone.utc)

        async def hazards(count: int) -> None:
            store = console.service.repositories.hazards
            for seq in range(count):
                event = {"body": at(hazard(seq, description=f"hazard {seq + 1}"), INSIDE["x"], INSIDE["y"])}
                when = received + timedelta(seconds=seq)
                await store.add_hazard("default", "explorer1", "e", seq, event, when, held=False)

        console.run(lambda: hazards(15))
        with http_session(console, "oper1") as http:
            page = http.get("/console/map").text
            assert [f'id="map-hazard-default-{n}"' in page for n in (15, 14, 13)] == [True, True, False]
            assert 'id="map-hazards-announced">15<' in page
            assert "announced: the newest 2 of 15 drawn and listed" in page
            dashboard = http.get("/console/").text
            assert 'id="hazards-announced">15<' in dashboard and "and 3 more" in dashboard
            assert 'id="dashboard-hazard-default-15"' in dashboard
            assert 'id="dashboard-hazard-default-3"' not in dashboard, "the twelve newest are listed"


def test_a_hazard_stored_before_it_is_registered_is_drawn_by_the_next_render(bus: Bus) -> None:
    """The worker stores a hazard's event, then registers the hazard (gives it its id): a render the
    event asked for may come in between. The map then renders again at the next call, not after its
    interval, until it draws the hazard."""
    with running_console(bus) as console:
        service = console.service
        view = MapView(service, Latest(service.events))
        now = datetime.now(timezone.utc)
        record = EventRecord(
            "explorer1", "e-1", 0, "hazard", "m-0", now, now, {**hazard(), "description": "Gas"},
            "explorer1", "explorer1.events", "explorer1.hazard",
        )  # fmt: skip

        async def stored_then_registered() -> tuple[str, str]:
            await service.repositories.events.write_events([record])
            # at once, from the event: a provisional mark, for the page's list of them
            (news,) = await view.events([record])
            assert news.startswith('<li id="mark-new-explorer1-e-1-0" data-into="map-news"'), news
            assert 'data-event="explorer1-e-1-0"' in news and 'data-label="new"' in news, news
            before = (await view.snapshot())[0]  # the render the event asked for, too early
            await service.repositories.hazards.hold_hazards([NewHazard.of(record)])
            return before, (await view.snapshot())[0]  # well within the interval

        before, after = console.run(stored_then_registered)
        assert "mark-hazard-default-1" not in before
        assert 'id="mark-hazard-default-1" class="hazard state-held" data-event="explorer1-e-1-0"' in after
