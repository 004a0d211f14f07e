"""The files and folders the architecture page and the README's layout table name exist."""

from __future__ import annotations

import re

from tests.docs.pages import ROOT

NAME = re.compile(r"`([\w./-]+(?:\.py|/))`")


def named_in_rows(page: str) -> list[tuple[str, str]]:
    """(package folder, name) for each file or folder a ``| `package/` | ... |`` row names."""
    found = []
    for line in (ROOT / page).read_text().splitlines():
        if match := re.match(r"\| `([\w/]+)/` \|(.*)", line):
            found += [(match[1], name) for name in NAME.findall(match[2])]
    return found


def exists(package: str, name: str) -> bool:
    if (ROOT / name).exists() or (ROOT / package / name).exists():
        return True
    return name.endswith(".py") and "/" not in name and any((ROOT / package).rglob(name))


def test_every_path_of_the_architecture_and_the_layout_exists() -> None:
    named = named_in_rows("docs/architecture.md") + named_in_rows("README.md")
    assert len(named) > 50, "the tables' names were found"
    missing = [f"{package}/: {name}" for package, name in named if not exists(package, name)]
    assert not missing, f"named but not in the repository: {missing}"


def test_every_link_of_the_readme_is_to_a_file_of_the_repository() -> None:
    """The README is read on the forge as well as in the site, where the generated reference
    pages (docs_hooks) exist only once built: its links must hold without the build."""
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", (ROOT / "README.md").read_text())
    local = [link for link in links if "://" not in link and not link.startswith("mailto:")]
    assert len(local) > 10, "the README's links were found"
    assert [link for link in local if not (ROOT / link).exists()] == []
