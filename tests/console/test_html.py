"""The HTML the console serves, checked by the Nu Html Checker (vnu, the W3C's validator, pinned
with the Node.js peers in ``tests/peers/package.json``): the login page, the page that refuses a
role, and every page for every role that may open it. htmx's own attributes (``hx-get``, ...) are
the one thing allowed beyond HTML: htmx also reads them as ``data-hx-*``, which is valid, but that
would rename every attribute of every template and of the tests that read them."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import httpx

from fleetbus.api.console.sitemap import MESSAGES
from fleetbus.schemas.roles import UserRole
from tests.console.every_page import ROLES, page_paths, stage_team
from tests.console.support import running_console
from tests.peers import java, node_module_file
from tests.support import Bus

#: What the checker says of htmx's attributes, left out.
HTMX = re.compile(r"^Attribute “hx-[a-z-]+” not allowed on element “[a-z]+” at this point\.$")


def checked(pages: dict[Path, str]) -> list[str]:
    """Each error the checker finds in the ``pages`` (files, by what they show), as a sentence."""
    jar = node_module_file("vnu-jar/build/dist/vnu.jar")
    command = [java(), "-jar", str(jar), "--errors-only", "--format", "json", *map(str, pages)]
    ran = subprocess.run(command, capture_output=True, text=True, timeout=300)
    shown_in = {path.resolve(): shown for path, shown in pages.items()}
    problems = []
    for message in json.loads(ran.stderr)["messages"]:
        if HTMX.match(message.get("message", "")):
            continue
        url = message.get("url", "?")  # file:/tmp/...
        where = shown_in.get(Path(url.removeprefix("file:")).resolve(), url)
        extract = " ".join(message.get("extract", "").split())
        problems.append(f"{where}, line {message.get('lastLine', '?')}: {message['message']} ({extract})")
    return problems


def test_every_page_is_valid_html_for_every_role(bus: Bus, tmp_path: Path) -> None:
    pages: dict[Path, str] = {}

    def keep(html: str, shown: str) -> None:
        path = tmp_path / f"page-{len(pages)}.html"
        path.write_text(html)
        pages[path] = shown

    with running_console(bus) as console:
        stage_team(console)
        with httpx.Client(base_url=console.base, timeout=30) as http:
            keep(http.get("/console/login").text, "the login page")
        for role, name in ROLES.items():
            with console.http_as(name) as http:
                for path in page_paths(role):
                    answer = http.get(path)
                    assert answer.status_code == 200, f"{path} as {role.value}: {answer.status_code}"
                    keep(answer.text, f"{path} as {role.value}")
        with console.http_as(ROLES[UserRole.PLANNER]) as http:
            refused = http.get(MESSAGES.path)
            assert refused.status_code == 403
            keep(refused.text, f"{MESSAGES.path} refused to a planner")
    assert len(pages) > 2 * len(ROLES)
    assert checked(pages) == []
