"""The command lines the documentation shows, read from its Markdown as a reader sees them.

The rules (also in docs/contributing.md, "Commands in the documentation"):

- A fenced block whose language is ``sh``, ``bash`` or ``shell`` holds commands only: every line
  that is not blank or a ``#`` comment is a command (a line ending in ``\\`` goes on on the next).
- A ``console`` block is a transcript: a line starting with ``$ `` is a command, the others are
  what it printed.
- Any other block (no language, ``text``, ``yaml``...) may hold no command: a line in it that starts
  with ``$ `` or with a command word (``fleetbus``, ``bash``, ``curl``, ``docker``...) is an error,
  so that no command is shown where it would not be run.
- An HTML comment on the line before a block says something about the whole block:
  ``<!-- not run here: REASON -->``: its commands are not run (their parser is still checked);
  ``<!-- file: NAME -->``: the block is written to the file NAME before the page's commands run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SHELL_LANGUAGES = frozenset({"sh", "bash", "shell"})
TRANSCRIPT_LANGUAGE = "console"
#: The first word of a line that is a command wherever it stands (checked outside shell blocks).
COMMAND_WORDS = (
    "fleetbus",
    "bash",
    "sh",
    "sudo",
    "python",
    "python3",
    "pip",
    "curl",
    "docker",
    "export",
    "rabbitmqctl",
    "rabbitmq-queues",
    "rabbitmq-plugins",
    "openssl",
    "npm",
    "node",
)
COMMAND_START = re.compile(r"^(\$ |(\.venv/bin/)?(" + "|".join(map(re.escape, COMMAND_WORDS)) + r")( |$))")
FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`\s]*)")
MARKER = re.compile(r"^\s*<!--\s*(?P<key>not run here|file)\s*:\s*(?P<value>.*?)\s*-->\s*$")


@dataclass(frozen=True)
class Command:
    """One command line as the page shows it."""

    page: str  # relative to the repository's root
    line: int  # of its first line in the page
    text: str  # continuation lines joined; a trailing comment kept (the shell ignores it)
    not_run: str | None = None  # the reason the page gives, when it is not run here

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


@dataclass
class Page:
    path: str
    commands: list[Command] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)  # name -> content, from `<!-- file: NAME -->`
    problems: list[str] = field(default_factory=list)  # what breaks the rules above


def documentation_pages() -> list[Path]:
    """README.md and every Markdown page under docs/, in a stable order."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def read_page(path: Path) -> Page:
    relative = path.relative_to(ROOT).as_posix()
    page = Page(relative)
    lines = path.read_text().splitlines()
    index = 0
    while index < len(lines):
        opening = FENCE.match(lines[index])
        if not opening:
            index += 1
            continue
        markers = _markers_before(lines, index)
        fence = opening["fence"]
        closing = re.compile(rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$")
        body_start = index + 1
        end = body_start
        while end < len(lines) and not closing.match(lines[end]):
            end += 1
        indent = len(opening["indent"])
        body = [
            text[indent:] if not text[:indent].strip() else text.lstrip() for text in lines[body_start:end]
        ]
        _read_block(page, opening["info"].lower(), body, body_start + 1, markers)
        index = end + 1
    return page


def _markers_before(lines: list[str], fence_index: int) -> dict[str, str]:
    """The `<!-- key: value -->` comments directly above a fence (blank lines between are allowed)."""
    found: dict[str, str] = {}
    index = fence_index - 1
    while index >= 0 and not lines[index].strip():
        index -= 1
    while index >= 0 and (match := MARKER.match(lines[index])):
        found[match["key"]] = match["value"]
        index -= 1
    return found


def _read_block(page: Page, language: str, body: list[str], first_line: int, markers: dict[str, str]) -> None:
    if "file" in markers:
        page.files[markers["file"]] = "\n".join(body) + "\n"
    not_run = markers.get("not run here")
    if not_run is not None and not not_run:
        page.problems.append(f"{page.path}:{first_line - 1}: `not run here` needs its reason after the colon")
    if language in SHELL_LANGUAGES:
        for line, text in _joined(body, first_line, transcript=False):
            page.commands.append(Command(page.path, line, text, not_run))
    elif language == TRANSCRIPT_LANGUAGE:
        for line, text in _joined(body, first_line, transcript=True):
            page.commands.append(Command(page.path, line, text, not_run))
    else:
        for offset, text in enumerate(body):
            if COMMAND_START.match(text):
                page.problems.append(
                    f"{page.path}:{first_line + offset}: a command in a ```{language or ' '} block, where "
                    f"it is not run: show commands in a ```sh block (or ```console with `$ ` for a "
                    f"transcript): {text.strip()[:80]}"
                )
    if not_run is not None and language not in SHELL_LANGUAGES | {TRANSCRIPT_LANGUAGE}:
        page.problems.append(f"{page.path}:{first_line - 1}: `not run here` above a block without commands")


def _joined(body: list[str], first_line: int, transcript: bool) -> list[tuple[int, str]]:
    """(line, command) for each command of a shell block or transcript, continuations joined."""
    commands: list[tuple[int, str]] = []
    current: list[str] = []
    start = 0
    for offset, raw in enumerate(body):
        text = raw.rstrip()
        if not current:
            if transcript:
                if not text.startswith("$ "):
                    continue
                text = text[2:]
            if not text.strip() or text.lstrip().startswith("#"):
                continue
            start = first_line + offset
        if text.endswith("\\"):
            current.append(text[:-1].rstrip())
            continue
        current.append(text.strip() if current else text)
        commands.append((start, " ".join(part.strip() for part in current)))
        current = []
    if current:
        commands.append((start, " ".join(part.strip() for part in current)))
    return commands
