"""Whether a page holds at a window size: no interactive control outside the viewport, cut off by
a container that clips, or hidden behind a container's scrollbar; and no page that scrolls
sideways. Measured by the browser itself (its layout, not ours)."""

from __future__ import annotations

from tests.console.support import Browser

#: The sizes every page must hold at: a laptop's screen, and a tablet held upright.
SIZES = ((1280, 800), (768, 1024))

#: Runs in the page: each problem as a sentence naming the control and what hides it. Controls
#: inside the map's panes (markers panned out of view) are the map's content, not its controls.
CHECK = r"""
const width = document.documentElement.clientWidth;
const problems = [];
function name(el) {
  const text = (el.innerText || el.value || el.getAttribute('aria-label') || el.name || '')
    .replace(/\s+/g, ' ').trim();
  const id = el.id ? '#' + el.id : '';
  return el.tagName.toLowerCase() + id + (text ? ' "' + text.slice(0, 40) + '"' : '');
}
if (document.documentElement.scrollWidth > width + 1) {
  const wide = document.documentElement.scrollWidth;
  problems.push('the page scrolls sideways: ' + wide + ' px wide in ' + width);
}
const controls = 'a[href], button, input:not([type=hidden]), select, textarea, summary, [tabindex]';
for (const el of document.querySelectorAll(controls)) {
  if (el.closest('.leaflet-pane')) continue;
  const r = el.getBoundingClientRect();
  if (r.width === 0 && r.height === 0) continue;
  if (r.left < -1 || r.right > width + 1) {
    const span = Math.round(r.left) + ' to ' + Math.round(r.right);
    problems.push(name(el) + ' outside the viewport (' + span + ' of ' + width + ')');
    continue;
  }
  for (let box = el.parentElement; box && box !== document.body; box = box.parentElement) {
    const style = getComputedStyle(box);
    if (style.overflowX === 'visible') continue;
    const b = box.getBoundingClientRect();
    if (r.left < b.left - 1 || r.right > b.right + 1) {
      problems.push(name(el) + ' cut off by ' + name(box) + ' (' + style.overflowX + ')');
      break;
    }
  }
}
return problems;
"""


def set_viewport(browser: Browser, width: int, height: int) -> None:
    """The page's viewport, exactly (the window's size would include whatever chrome it draws)."""
    browser.driver.execute_cdp_cmd(
        "Emulation.setDeviceMetricsOverride",
        {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
    )


def reset_viewport(browser: Browser) -> None:
    browser.driver.execute_cdp_cmd("Emulation.clearDeviceMetricsOverride", {})


def overflows(browser: Browser) -> list[str]:
    """What the page in ``browser`` cuts off or hides, as sentences (none when it holds)."""
    return browser.driver.execute_script(CHECK)
