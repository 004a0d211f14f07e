"""Profiles of the fleetbus processes a benchmark starts, and where their samples land.

    .venv/bin/python -m bench --only hazard --profile     # py-spy records each fleetbus process
    .venv/bin/python -m bench.profile bench/results/profiles/*.speedscope.json

With ``--profile`` (which sets FLEETBUS_BENCH_PROFILE to a folder) every `fleetbus worker` or
`fleetbus recorder run` the suite starts is recorded by py-spy (250 samples a second, idle
samples left out) into ``<folder>/<scenario>-<command>-<pid>.speedscope.json``: open one in
https://www.speedscope.app, or run this module on them for each thread's busiest files.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

from rich.console import Console
from rich.table import Table

PROJECT_ROOT = Path(__file__).resolve().parent.parent
FOLDER_VARIABLE = "FLEETBUS_BENCH_PROFILE"
SCENARIO_VARIABLE = "FLEETBUS_BENCH_SCENARIO"
RATE = 250


def py_spy() -> str:
    found = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(found).exists():
        raise RuntimeError("--profile needs py-spy: .venv/bin/pip install py-spy")
    return found


def record(pid: int, command: str) -> subprocess.Popen[bytes] | None:
    """Start py-spy on ``pid`` when profiling is on; it stops, writing its file, when ``pid`` ends."""
    folder = os.environ.get(FOLDER_VARIABLE)
    if not folder:
        return None
    scenario = os.environ.get(SCENARIO_VARIABLE, "bench")
    path = Path(folder) / f"{scenario}-{command}-{pid}.speedscope.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    options = ["--format", "speedscope", "--output", str(path), "--rate", str(RATE), "--threads"]
    return subprocess.Popen(
        [py_spy(), "record", "--pid", str(pid), *options],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def where(frame: dict[str, object]) -> str:
    """The package a frame runs in: ``aiormq``, ``asyncio``, ``selectors.py``; this project's by
    folder (``workers``, ``workers/store``)."""
    path = Path(str(frame.get("file") or "?"))
    parts = path.parts
    for anchor in ("site-packages", *(f"python3.{minor}" for minor in range(10, 14))):
        if anchor in parts and len(parts) > parts.index(anchor) + 1:
            return parts[parts.index(anchor) + 1]
    if path.is_relative_to(PROJECT_ROOT):
        return str(path.parent.relative_to(PROJECT_ROOT)) or path.name
    return path.name


def busiest(path: Path, top: int = 10) -> list[tuple[str, float, list[tuple[str, float]]]]:
    """Per thread: seconds sampled, and the packages its innermost frames were in, with their share."""
    profile = json.loads(path.read_text())
    frames = profile["shared"]["frames"]
    threads = []
    for thread in profile["profiles"]:
        files: Counter[str] = Counter()
        for stack, weight in zip(thread["samples"], thread["weights"], strict=True):
            files[where(frames[stack[-1]]) if stack else "?"] += weight  # innermost frame last
        total = sum(files.values())
        threads.append((thread["name"], total, [(f, s / total) for f, s in files.most_common(top)]))
    return sorted(threads, key=lambda found: -found[1])


def main() -> None:
    console = Console()
    for name in sys.argv[1:]:
        table = Table(title=f"{name}: where the samples land (the innermost frame's package)")
        for column in ("thread", "seconds sampled", "package", "share"):
            table.add_column(column, justify="right" if column in ("seconds sampled", "share") else "left")
        for thread, seconds, files in busiest(Path(name)):
            for i, (file, share) in enumerate(files):
                table.add_row(
                    thread if i == 0 else "", f"{seconds:.1f}" if i == 0 else "", file, f"{share:.0%}"
                )
            table.add_section()
        console.print(table)


if __name__ == "__main__":
    main()
