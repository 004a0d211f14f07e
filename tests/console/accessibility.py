"""What axe-core finds wrong in the page as it is now: Deque's accessibility engine (pinned in
``tests/peers/package.json``), run in the browser on the rendered page. It checks what the layout
test cannot see: text contrast, the names of links, buttons and fields, headings, landmarks and
table headers, by the WCAG 2.1 A and AA rules and axe's best practices."""

from __future__ import annotations

from functools import cache

from tests.console.support import Browser
from tests.peers import node_module_file

#: The rule sets run: the WCAG 2.1 levels a public service is held to, and axe's best practices.
TAGS = ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa", "best-practice"]

#: Runs axe on the document; its violations as ``[rule, impact, help, [target: summary, ...]]``.
RUN = """
const done = arguments[arguments.length - 1];
axe.run(document, {runOnly: {type: "tag", values: arguments[0]}, resultTypes: ["violations"]})
  .then((result) => done(result.violations.map((v) => [v.id, v.impact, v.help,
    v.nodes.map((n) => n.target.join(" ") + ": " + n.failureSummary.replace(/\\s+/g, " "))])))
  .catch((error) => done([["axe failed", "error", String(error), []]]));
"""


@cache
def _axe() -> str:
    return node_module_file("axe-core/axe.min.js").read_text()


def violations(browser: Browser, where: str) -> list[str]:
    """Each rule the page breaks, as a sentence naming ``where``, the rule and the elements; once
    the page has put its alerts banner in (it loads it as it opens)."""
    browser.until(lambda: not browser.find("#alerts-banner-slot"), f"{where}: the alerts banner loaded")
    if not browser.driver.execute_script("return typeof window.axe !== 'undefined'"):
        browser.driver.execute_script(_axe())
    found = browser.driver.execute_async_script(RUN, TAGS)
    return [
        f"{where}: {rule} ({impact}): {help_text}: " + "; ".join(nodes[:5])
        for rule, impact, help_text, nodes in found
    ]
