"""The benchmark suite: every scenario, several runs each, in one command.

    .venv/bin/python -m bench [--runs 3] [--quick] [--only raw,ingest,...] [--list]

Runs are interleaved (run 1 of every scenario, then run 2, ...), so a slow spell of a shared
machine hits them alike and a target measured against the raw broker compares figures taken
minutes apart at most. Each scenario reports the median and the spread (min-max) of its
figures; the targets are checked on them. Results go to ``bench/results/suite-<UTC time>.json``
and ``.md`` (the Markdown the README's performance section shows). Interrupted (Ctrl-C) or stopped
(SIGTERM, as a CI job's timeout or a supervisor stops it), it reports and writes what it measured
so far. Each run's wall time is printed as it ends, with a note when it took longer than its
budget in the registry, and the suite's at the end; the default run fits in 12 minutes on a quiet
2-core machine.
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
from collections import deque
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

from bench import profile
from bench.registry import DEFAULT_RUNS, SCENARIOS, budget, by_name
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
    """Every run of ``scenarios``, interleaved. Ctrl-C (or SIGTERM, see :func:`main`) anywhere in
    them ends the loop with the outcomes so far: the run in hand, or the next one when the signal
    came between two runs, is marked as interrupted."""
    outcomes = {s.name: Outcome(s, s.runs(runs)) for s in scenarios}
    task = progress.add_task("", total=sum(o.planned for o in outcomes.values()))
    pending = deque((number, o) for number in range(runs) for o in outcomes.values() if number < o.planned)
    try:
        while pending:
            number, outcome = pending[0]
            if outcome.skipped is None:
                one_run(outcome, number, context, progress, task)
            pending.popleft()
    except KeyboardInterrupt:
        # past a run that ended as the signal came, and a scenario skipped
        while pending and (pending[0][0] in pending[0][1].runs or pending[0][1].skipped is not None):
            pending.popleft()
        if pending:
            number, outcome = pending[0]
            outcome.errors.append("interrupted")
            progress.console.print(
                f"[red]{run_name(outcome, number)} interrupted: reporting the runs done so far[/red]"
            )
    return outcomes


def run_name(outcome: Outcome, number: int) -> str:
    return f"run {number + 1}/{outcome.planned} {outcome.scenario.name}"


def one_run(outcome: Outcome, number: int, context: Context, progress: Progress, task: TaskID) -> None:
    """Run ``number`` of a scenario into its outcome; a line says how long it took, when it ends."""
    name = run_name(outcome, number)
    context.show = lambda text: progress.update(task, description=f"{name}: {text}")
    context.show("starting")
    if os.environ.get(profile.FOLDER_VARIABLE):
        os.environ[profile.SCENARIO_VARIABLE] = outcome.scenario.name  # names its profiles
    started = time.monotonic()
    try:
        try:
            outcome.runs[number] = outcome.scenario.measure(context)
        except Skip as skip:
            outcome.skipped = str(skip)
            progress.advance(task, outcome.planned - number - 1)
        except Exception as error:
            outcome.errors.append(f"{type(error).__name__}: {error}")
            progress.console.print(f"[red]{name} failed[/red]")
            progress.console.print(traceback.format_exc(), markup=False, highlight=False)
    finally:  # an interrupted run's time counts too
        seconds = time.monotonic() - started
        outcome.seconds += seconds
    progress.advance(task)
    if outcome.skipped is not None:
        note = f" (skipped: {outcome.skipped})"
    elif seconds > outcome.scenario.budget_s:
        note = f" [yellow](over its budget of {outcome.scenario.budget_s:g} s)[/yellow]"
    else:
        note = ""
    progress.console.print(f"{name}: {seconds:.1f} s{note}", highlight=False)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--runs", type=int, default=DEFAULT_RUNS, help=f"runs of each scenario (default {DEFAULT_RUNS})"
    )
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
        outcomes: dict[str, Outcome] = {}
        try:
            if not args.quick:
                console.print(f"{budget(scenarios, args.runs) / 60:.1f} min by the scenarios' budgets")
            with Progress(*columns, console=console) as progress:
                outcomes = run(scenarios, context, args.runs, progress)
        except KeyboardInterrupt:  # as the progress bar started or stopped: outside any run
            pass
        finally:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second one must not stop the writing
        try:
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
            write(meta, outcomes, stem)
        finally:
            signal.signal(signal.SIGTERM, previous)
    if args.profile:
        console.print(f"profiles in {os.environ[profile.FOLDER_VARIABLE]}: python -m bench.profile FILE")
    return 1 if any(o.errors for o in outcomes.values()) else 0


def write(meta: dict[str, Any], outcomes: dict[str, Outcome], stem: Path) -> None:
    """The tables on the console and in ``stem``.json and .md; the suite's wall time last."""
    found = verdicts(outcomes)
    for table in tables(outcomes, found):
        console.print(table)
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".json").write_text(json.dumps(as_json(meta, outcomes, found), indent=2))
    stem.with_suffix(".md").write_text(markdown(meta, outcomes, found))
    console.print(f"wrote {stem}.json and {stem}.md")
    console.print(
        f"the suite took {meta['seconds'] / 60:.1f} min ({meta['seconds']:.0f} s); "
        f"load average at the end {meta['load at the end']}",
        highlight=False,
    )
