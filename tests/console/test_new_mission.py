"""A new mission drawn on the team's map in a real browser: the geofence clicked vertex by vertex,
a point of interest dropped and renamed, the summary, back to the form, the summary again and
Confirm; the mission stored with the coordinates drawn, nothing before Confirm. The map's files
all from fleetbus itself, nothing refused by the console's Content-Security-Policy."""

from __future__ import annotations

import base64
import hashlib
from datetime import datetime, timezone

from selenium.webdriver.common.action_chains import ActionChains

from fleetbus.schemas.roles import UserRole
from tests.console.layout import SIZES, overflows, reset_viewport, set_viewport
from tests.console.support import Browser, Console, running_console
from tests.console.test_missions import mission, state
from tests.factories import small_map
from tests.support import Bus

#: small_map's world: 64 x 48 pixels of 0.11 m from (2.1, 3.5): x 2.1 to 9.14, y 3.5 to 8.78.
CENTRE = ((2.1 + 9.14) / 2, (3.5 + 8.78) / 2)
#: Where the test clicks the geofence's vertices: pixels from the map's centre, x right, y down.
CLICKS = [(-120, -80), (120, -80), (120, 80), (-120, 80)]


def _stored_map(console: Console) -> None:
    """small_map stored as version 1, as the worker stores an explorer's map."""
    made = small_map()
    image = base64.b64decode(made["pgm"])
    digest = hashlib.sha256(image).hexdigest()
    maps = console.service.repositories.maps
    now = datetime.now(timezone.utc)
    console.run(
        lambda: maps.commit_map("explorer1", "e1", 1, image, made["metadata"], now, digest, 4096, None)
    )


def _ready(browser: Browser) -> bool:
    """The plan's map drawn, over the map's image once loaded."""
    return browser.driver.execute_script(
        "const view = document.getElementById('plan-map'), image = document.getElementById('plan-image');"
        "return !!(view && view.dataset.ready && image && image.complete && image.naturalWidth === 64)"
    )


def _click_map(browser: Browser, dx: int, dy: int) -> None:
    """Click ``dx``, ``dy`` pixels from the map's centre (the map all in view: Selenium measures from
    the centre of the part in view)."""
    view = browser.find("#plan-map")[0]
    browser.driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", view)
    ActionChains(browser.driver).move_to_element_with_offset(view, dx, dy).click().perform()


def _tool(browser: Browser, shape: str) -> None:
    """Press Leaflet-Geoman's toolbar button drawing ``shape`` (polygon, marker...)."""
    browser.click(f".leaflet-pm-toolbar .leaflet-pm-icon-{shape}")


def _field(browser: Browser, name: str) -> list[str]:
    value = browser.find(f"textarea[name={name}]")[0].get_attribute("value")
    return [line.strip() for line in value.splitlines() if line.strip()]


def _points(lines: list[str]) -> list[tuple[float, float]]:
    return [(float(x), float(y)) for x, y in (line.split() for line in lines)]


def test_a_mission_drawn_on_the_map_is_created_only_on_confirm_with_its_coordinates(
    bus: Bus, browser: Browser
) -> None:
    with running_console(bus) as console:
        console.user("plan1", UserRole.PLANNER)
        _stored_map(console)
        console.log_in(browser, "plan1")
        browser.console_errors()  # what the earlier pages logged, set aside
        browser.go(console.url("/console/missions/new"))
        browser.until(lambda: _ready(browser), "the team's map under the plan")
        browser.fill("input[name=title]", "North yard sweep")

        _tool(browser, "polygon")
        for dx, dy in [*CLICKS, CLICKS[0]]:  # the first vertex again closes it
            _click_map(browser, dx, dy)
        browser.until(lambda: len(_field(browser, "geofence")) == 4, "the geofence's 4 vertices written")
        browser.until(lambda: browser.find("path.geofence[data-vertices='4']"), "the geofence drawn")
        fence = _points(_field(browser, "geofence"))
        (west, north), (east, _), (_, south), _ = fence
        assert fence == [(west, north), (east, north), (east, south), (west, south)], "in the clicked order"
        # the map frame's metres: y up, one scale both ways, the map's centre the image's
        assert east > west and north > south
        assert abs((east - west) / (north - south) - 240 / 160) < 0.02
        assert abs((west + east) / 2 - CENTRE[0]) < 0.05 and abs((north + south) / 2 - CENTRE[1]) < 0.05

        _tool(browser, "marker")
        _click_map(browser, 0, 0)
        browser.until(lambda: _field(browser, "points_of_interest"), "the point of interest written")
        [dropped] = _field(browser, "points_of_interest")
        name, x, y = (part.strip() for part in dropped.split(","))
        assert name == "point 1"
        assert abs(float(x) - CENTRE[0]) < 0.05 and abs(float(y) - CENTRE[1]) < 0.05
        _tool(browser, "marker")  # done dropping
        browser.fill("textarea[name=points_of_interest]", f"gate, {x}, {y}, north entrance")
        browser.until(lambda: browser.find(".leaflet-marker-icon[data-poi='gate']"), "renamed on the map")

        loaded = browser.driver.execute_script(
            "return performance.getEntriesByType('resource').map((entry) => entry.name)"
        )
        assert all(url.startswith(console.base) for url in loaded), loaded
        assert any("/vendor/leaflet-geoman-2.20.2/leaflet-geoman.min.js" in url for url in loaded)

        browser.click("button[data-action=summary]")
        browser.until(lambda: browser.find("#confirm-form"), "the summary")
        browser.until(lambda: browser.find("#plan-map[data-ready] path.geofence"), "the summary's map")
        listed = [
            (float(item.get_attribute("data-x")), float(item.get_attribute("data-y")))
            for item in browser.find("#summary-geofence li")
        ]
        assert listed == fence
        assert browser.texts("#summary-pois li") == [f"gate ({float(x)}, {float(y)}) north entrance"]
        assert browser.find("#plan-map .leaflet-marker-icon[data-poi='gate']")
        assert browser.text("#summary-title") == "North yard sweep"
        assert console.run(console.service.repositories.missions.missions) == [], "nothing yet"
        try:  # the summary holds on a laptop and a tablet, as every page (test_layout)
            for width, height in SIZES:
                set_viewport(browser, width, height)
                assert overflows(browser) == [], f"the summary at {width}x{height}"
        finally:
            reset_viewport(browser)

        browser.click("button[data-action=edit]")
        browser.until(lambda: browser.find("form.mission-form") and _ready(browser), "back on the form")
        assert browser.find("input[name=title]")[0].get_attribute("value") == "North yard sweep"
        assert _points(_field(browser, "geofence")) == fence
        assert browser.find("path.geofence[data-vertices='4']"), "the geofence drawn again"
        assert console.run(console.service.repositories.missions.missions) == []

        browser.click("button[data-action=summary]")
        browser.until(lambda: browser.find("#confirm-form"), "the summary again")
        browser.click("button[data-action=confirm]")
        browser.until(lambda: state(browser) == "planning", "the mission created")
        assert "Mission created." in browser.text("main")
        plan = mission(console).plan
        assert [(p["x"], p["y"]) for p in plan["geofence"]["polygon"]] == fence
        assert plan["points_of_interest"] == [
            {"name": "gate", "x": float(x), "y": float(y), "note": "north entrance"}
        ]
        assert browser.console_errors() == []
