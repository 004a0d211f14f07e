"""The benchmark suite: every scenario, several runs each, in one command.

    .venv/bin/python -m bench [--runs 3] [--quick] [--only raw,ingest,...] [--list]

Runs are interleaved (run 1 of every scenario, then run 2, ...), so a slow spell of a shared
machine hits them alike and a target measured against the raw broker compares figures taken
minutes apart at most. Each scenario reports the median and the spread (min-max) of its
figures; the targets are checked on them. Results go to ``bench/results/suite-<UTC time>.json``
and ``.md`` (the Markdown the README's performance section shows). Interrupted (Ctrl-C) or stopped
(SIGTERM, as a CI job's timeout or a supervisor stops it), it reports and writes what it measured
so far.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import sys
import time
import traceback
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from bench import profile
from bench.registry import SCENARIOS, by_name
from bench.report import Outcome, as_json, load_average, machine, markdown, tables, verdicts
from bench.scenario import Context, Scenario, Skip
from fleetbus.broker.management import ManagementAPI
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker

console = Console()


def select(only: str | None) -> list[Scenario]:
    """The scenarios asked for, with those their targets compare with, in the registry's order."""
    scenarios = by_name()
    if not only:
        return list(SCENARIOS)
    asked = [name.strip() for name in only.split(",") if name.strip()]
    unknown = [name for name in asked if name not in scenarios]
    if unknown:
        raise SystemExit(f"unknown scenario {', '.join(unknown)}; known: {', '.join(scenarios)}")
    wanted = set(asked)
    for name in asked:
        added = set(scenarios[name].needs) - wanted
        if added:
            console.print(f"also running {', '.join(sorted(added))}: {name}'s targets compare with it")
            wanted |= added
    return [scenario for scenario in SCENARIOS if scenario.name in wanted]


def run(scenarios: Sequence[Scenario], context: Context, runs: int, progress: Progress) -> dict[str, Outcome]:
    outcomes = {s.name: Outcome(s, s.runs(runs)) for s in scenarios}
    task = progress.add_task("", total=sum(o.planned for o in outcomes.values()))
    for number in range(runs):
        for outcome in outcomes.values():
            if number >= outcome.planned or outcome.skipped is not None:
                continue
            name = f"run {number + 1}/{outcome.planned} {outcome.scenario.name}"
            context.show = lambda text, name=name: progress.update(task, description=f"{name}: {text}")
            context.show("starting")
            if os.environ.get(profile.FOLDER_VARIABLE):
                os.environ[profile.SCENARIO_VARIABLE] = outcome.scenario.name  # names its profiles
            started = time.monotonic()
            try:
                outcome.runs[number] = outcome.scenario.measure(context)
            except Skip as skip:
                outcome.skipped = str(skip)
                progress.advance(task, outcome.planned - number - 1)
            except Exception as error:
                outcome.errors.append(f"{type(error).__name__}: {error}")
                progress.console.print(f"[red]{name} failed[/red]")
                progress.console.print(traceback.format_exc(), markup=False, highlight=False)
            except KeyboardInterrupt:  # Ctrl-C: report what was measured so far
                outcome.errors.append("interrupted")
                progress.console.print(f"[red]{name} interrupted: reporting the runs done so far[/red]")
                return outcomes
            outcome.seconds += time.monotonic() - started
            progress.advance(task)
    return outcomes


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=3, help="runs of each scenario (default 3)")
    parser.add_argument("--quick", action="store_true", help="smaller runs: a few minutes in all")
    parser.add_argument("--only", help="comma-separated scenario names (see --list)")
    parser.add_argument("--list", action="store_true", help="list the scenarios and their targets, and exit")
    parser.add_argument("--out", type=Path, default=Path("bench/results"), help="where results go")
    parser.add_argument(
        "--profile", action="store_true", help="record each fleetbus process with py-spy (see bench.profile)"
    )
    args = parser.parse_args(argv)
    if args.list:
        for scenario in SCENARIOS:
            targets = "".join(f"\n    target: {t.measures()} {t.describe()}" for t in scenario.targets)
            console.print(f"[bold]{scenario.name}[/bold]: {scenario.what}{targets}", highlight=False)
        return 0
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    scenarios = select(args.only)
    started = datetime.now(timezone.utc)
    stem = args.out / f"suite-{started:%Y%m%dT%H%M%S}"
    if args.profile:
        profile.py_spy()  # fails now, not after the first scenario, when py-spy is missing
        os.environ[profile.FOLDER_VARIABLE] = str(args.out / f"profiles-{started:%Y%m%dT%H%M%S}")
    settings = load_settings()
    endpoint = resolve_broker(settings, start=True)
    clock = time.monotonic()
    command = " ".join(
        [".venv/bin/python -m bench", *map(shlex.quote, sys.argv[1:] if argv is None else argv)]
    )
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        where = machine(api, endpoint)
        context = Context(endpoint, api, quick=args.quick)
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
        # SIGTERM ends the suite as Ctrl-C does: the scenario in hand stops (its processes are
        # stopped by its own cleanup) and the runs measured so far are written
        previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
        try:
            with Progress(*columns, console=console) as progress:
                outcomes = run(scenarios, context, args.runs, progress)
        finally:
            signal.signal(signal.SIGTERM, previous)
    found = verdicts(outcomes)
    meta = {
        "command": command,
        "started": f"{started:%Y-%m-%d %H:%M} UTC",
        "finished": f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
        "seconds": time.monotonic() - clock,
        "load at the end": load_average(),
        "runs": args.runs,
        "quick": args.quick,
        "machine": where,
    }
    for table in tables(outcomes, found):
        console.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".json").write_text(json.dumps(as_json(meta, outcomes, found), indent=2))
    stem.with_suffix(".md").write_text(markdown(meta, outcomes, found))
    console.print(f"wrote {stem}.json and {stem}.md")
    if args.profile:
        console.print(f"profiles in {os.environ[profile.FOLDER_VARIABLE]}: python -m bench.profile FILE")
    return 1 if any(o.errors for o in outcomes.values()) else 0
