"""The console's dashboard and live map as a browser draws them: headless chromium (the one the
console's tests drive) logged in through the console's form, each page opened ``renders`` times
from a blank page (as in a new tab: no other page of the console to unload first).

- dashboard: from the navigation's start to the end of its ``load`` event (the page's HTML, its
  styles and scripts, the panels drawn);
- live map: from the navigation's start to the first frame in which Leaflet has a marker on the
  map for every mark the page lists (robots, hazards, beacons), which is what an operator waits
  for; and, of the map, when its HTML was received, parsed (the document interactive) and its
  deferred scripts had run, all from the same start.

Times are the browser's own (``performance``), so the driver's round trips are not in them.
"""

from __future__ import annotations

from collections.abc import Callable

from tests.console.support import start_chromium

#: Installed in every document before its own scripts run (through the DevTools protocol): from
#: the first frame on, it looks once a frame whether every mark the map page lists has its Leaflet
#: marker, and notes the time of the first frame where they all have.
_WATCH_MARKS = """
window.__marksDrawn = null;
function __lookForMarks() {
  const list = document.getElementById("map-marks");
  const listed = list ? list.children.length : 0;
  const drawn = document.querySelectorAll(".leaflet-marker-pane [data-mark]").length;
  if (listed > 0 && drawn >= listed) window.__marksDrawn = [performance.now(), listed];
  else requestAnimationFrame(__lookForMarks);
}
requestAnimationFrame(__lookForMarks);
"""
#: Resolves with what _WATCH_MARKS noted, once it has (or [-1, marks] after 30 s).
_MAP_DRAWN = """
const done = arguments[arguments.length - 1];
const started = performance.now();
(function wait() {
  if (window.__marksDrawn) return done(window.__marksDrawn);
  const list = document.getElementById("map-marks");
  if (performance.now() - started > 30000) return done([-1, list ? list.children.length : 0]);
  setTimeout(wait, 20);
})();
"""
_LOADED = "return performance.getEntriesByType('navigation')[0].loadEventEnd;"
#: Where a page's time went: its HTML received, then parsed (the document interactive), then its
#: deferred scripts run (DOMContentLoaded's end).
_STAGES = (
    "const n = performance.getEntriesByType('navigation')[0];"
    "return [n.responseEnd, n.domInteractive, n.domContentLoadedEventEnd];"
)
STAGES = ("HTML received", "HTML parsed", "scripts run")


def browser_times(
    base: str, user: str, password: str, renders: int, show: Callable[[str], None]
) -> dict[str, list[float]]:
    """ms for each render of the dashboard and the live map, after one render of each not counted."""
    driver = start_chromium()
    driver.set_script_timeout(40)
    driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": _WATCH_MARKS})
    try:
        driver.get(f"{base}/console/login")
        driver.find_element("css selector", "input[name=username]").send_keys(user)
        driver.find_element("css selector", "input[name=password]").send_keys(password)
        driver.find_element("css selector", "form button[type=submit]").click()
        times: dict[str, list[float]] = {"dashboard in chromium": [], "live map in chromium": []}
        for stage in STAGES:
            times[f"live map in chromium: {stage}"] = []
        for counted in [False] + [True] * renders:
            show("the dashboard and the map in chromium")
            driver.get("about:blank")
            driver.get(f"{base}/console/")  # returns once the page's load event ended
            loaded = float(driver.execute_script(_LOADED))
            driver.get("about:blank")
            driver.get(f"{base}/console/map")
            drawn, listed = driver.execute_async_script(_MAP_DRAWN)
            if drawn < 0:
                raise RuntimeError(f"the live map drew no marker for some of its {listed} marks in 30 s")
            stages = driver.execute_script(_STAGES)
            if counted:
                times["dashboard in chromium"].append(loaded)
                times["live map in chromium"].append(float(drawn))
                for stage, at in zip(STAGES, stages, strict=True):
                    times[f"live map in chromium: {stage}"].append(float(at))
        return times
    finally:
        driver.quit()
