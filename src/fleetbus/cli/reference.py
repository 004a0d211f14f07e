"""The command line reference, docs/reference/cli.md: typer's own Markdown of the ``fleetbus``
console script, kept in the repository so that it reads the same on the site and in a checkout.

    python -m fleetbus.cli.reference                                   # print it
    python -m fleetbus.cli.reference --update docs/reference/cli.md    # rewrite the page

A test fails while the page differs from the console script's parser.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

UPDATE = "python -m fleetbus.cli.reference --update docs/reference/cli.md"
HEADER = (
    f"<!-- generated from the console script's parser by `{UPDATE}`: edit the commands, not this page -->\n"
    "# Command line reference\n\n"
    "Every command of the `fleetbus` console script, with its arguments and options, as "
    "`fleetbus COMMAND --help` prints them. The guides say when to use which.\n"
)


def reference_page() -> str:
    """typer's ``utils docs`` of the app, under a title of the page's own; each usage line in a
    ``text`` block as ``--help`` prints it (``Usage: fleetbus ...``), since it is a synopsis and not a
    command to paste."""
    command = [sys.executable, "-m", "typer", "fleetbus.cli", "utils", "docs", "--name", "fleetbus"]
    text = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    body = text.split("\n", 1)[1]  # typer's own title, "# `fleetbus`"
    body = re.sub(r"\*\*Usage\*\*:\n\n```console\n\$ (.*?)\n```", r"```text\nUsage: \1\n```", body)
    return HEADER + body.rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m fleetbus.cli.reference", description="Print the command line reference (Markdown)."
    )
    parser.add_argument("--update", type=Path, metavar="FILE", help="write it to FILE instead")
    arguments = parser.parse_args(argv)
    page = reference_page()
    if arguments.update is None:
        sys.stdout.write(page)
        return
    current = arguments.update.read_text() if arguments.update.exists() else None
    if current != page:
        arguments.update.write_text(page)
    print(f"{arguments.update}: {'already up to date' if current == page else 'updated'}")


if __name__ == "__main__":
    main()
