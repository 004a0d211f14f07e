"""The suite's results: medians and spreads, the targets' verdicts, as rich tables, Markdown and JSON."""

from __future__ import annotations

import os
import platform
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.table import Table

from bench.scenario import Figures, Scenario, Target
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI


@dataclass
class Outcome:
    """What became of one scenario in the suite."""

    scenario: Scenario
    planned: int
    runs: dict[int, Figures] = field(default_factory=dict)
    """The figures of each run that succeeded, by the suite's run number (0, 1, ...)."""
    skipped: str | None = None
    errors: list[str] = field(default_factory=list)
    seconds: float = 0.0
    """Wall time of all its runs."""

    def figures(self) -> list[str]:
        names: dict[str, None] = {}
        for run in self.runs.values():
            names.update(dict.fromkeys(run))
        return list(names)

    def values(self, figure: str) -> list[float]:
        return [run[figure] for run in self.runs.values() if figure in run]

    @property
    def status(self) -> str:
        if self.skipped is not None:
            return f"skipped: {self.skipped}"
        if self.errors:
            return f"{len(self.errors)} of {self.planned} runs failed: {self.errors[0]}"
        return ""


@dataclass(frozen=True)
class Verdict:
    scenario: str
    measures: str
    target: str
    measured: float | None
    met: bool | None
    note: str = ""
    """Why there is no measurement."""

    @property
    def answer(self) -> str:
        if self.met is None:
            return f"not measured ({self.note})"
        return "yes" if self.met else "**no**"


def number(value: float) -> str:
    """Three significant figures or so, thousands separated."""
    if abs(value) >= 100:
        return f"{value:,.0f}"
    if abs(value) >= 10:
        return f"{value:.1f}"
    return f"{value:.2f}"


def spread(values: list[float]) -> str:
    return f"{number(min(values))}-{number(max(values))}"


def verdict(name: str, target: Target, outcomes: dict[str, Outcome]) -> Verdict:
    outcome = outcomes[name]
    baseline = outcomes.get(target.per[0]) if target.per else None
    what = (name, target.measures(), target.describe())
    if target.per and baseline is None:
        return Verdict(*what, None, None, f"{target.per[0]} was not run")
    for needed in (outcome, baseline):
        if needed is not None and not needed.runs:
            return Verdict(*what, None, None, needed.status or "no run")
    value = target.value(outcome.runs, baseline.runs if baseline else None)
    return Verdict(*what, value, target.met(value))


def verdicts(outcomes: dict[str, Outcome]) -> list[Verdict]:
    return [
        verdict(name, t, outcomes) for name, outcome in outcomes.items() for t in outcome.scenario.targets
    ]


def machine(api: ManagementAPI, endpoint: BrokerEndpoint) -> dict[str, str]:
    """Where the figures were measured."""
    cpu = next(
        (
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        ),
        platform.processor() or "unknown CPU",
    )
    memory_kb = next(
        int(line.split()[1])
        for line in Path("/proc/meminfo").read_text().splitlines()
        if line.startswith("MemTotal")
    )
    overview = api.overview()
    return {
        "cpu": f"{cpu}, {os.cpu_count()} cores",
        "memory": f"{memory_kb / 1024**2:.0f} GiB",
        "os": f"{platform.freedesktop_os_release().get('PRETTY_NAME', platform.system())}, "
        f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "broker": f"RabbitMQ {overview.get('rabbitmq_version', '?')} "
        f"(Erlang {overview.get('erlang_version', '?')}), {endpoint.kind} node",
        "load": load_average(),
    }


def load_average() -> str:
    """The 1, 5 and 15 minute load averages: how busy the shared machine was."""
    return "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def figure_rows(outcomes: dict[str, Outcome]) -> list[tuple[str, str, str, str, str]]:
    """(scenario, figure, median, spread, runs) for every figure; a row per skipped or failed scenario."""
    rows = []
    for name, outcome in outcomes.items():
        for figure in outcome.figures():
            values = outcome.values(figure)
            rows.append((name, figure, number(statistics.median(values)), spread(values), str(len(values))))
        if outcome.status:
            rows.append((name, outcome.status, "", "", str(len(outcome.runs))))
    return rows


TARGET_COLUMNS = ("scenario", "what", "measured", "target", "met")


def target_rows(found: list[Verdict]) -> list[tuple[str, str, str, str, str]]:
    return [
        (v.scenario, v.measures, "" if v.measured is None else number(v.measured), v.target, v.answer)
        for v in found
    ]


def tables(outcomes: dict[str, Outcome], found: list[Verdict]) -> list[Table]:
    figures = Table(title="figures: median of the runs, spread min-max")
    for column in ("scenario", "figure", "median", "spread", "runs"):
        figures.add_column(column, justify="right" if column in ("median", "spread", "runs") else "left")
    for row in figure_rows(outcomes):
        figures.add_row(*row)
    targets = Table(title="targets (ratios are run by run, against the raw broker of the same run)")
    for column in TARGET_COLUMNS:
        targets.add_column(column, justify="right" if column == "measured" else "left")
    for verdict_, row in zip(found, target_rows(found), strict=True):
        targets.add_row(
            *(cell.replace("**", "") for cell in row), style="red" if verdict_.met is False else None
        )
    return [figures, targets]


def _table(header: tuple[str, ...], rows: list[tuple[str, ...]], right: set[int]) -> list[str]:
    def escape(cell: str) -> str:
        return cell.replace("|", "\\|")

    lines = ["| " + " | ".join(header) + " |"]
    lines.append("| " + " | ".join("---:" if i in right else "---" for i in range(len(header))) + " |")
    lines += ["| " + " | ".join(escape(cell) for cell in row) + " |" for row in rows]
    return lines


def markdown(meta: dict[str, Any], outcomes: dict[str, Outcome], found: list[Verdict]) -> str:
    machine_ = meta["machine"]
    lines = [
        f"fleetbus benchmark suite, {meta['finished']} ({meta['seconds'] / 60:.1f} min): `{meta['command']}`",
        "",
        f"{machine_['cpu']}, {machine_['memory']}; {machine_['os']}; Python {machine_['python']}; "
        f"{machine_['broker']}; load average {machine_['load']} at the start, "
        f"{meta['load at the end']} at the end.",
        "Minutes per scenario: "
        + ", ".join(f"{name} {outcome.seconds / 60:.1f}" for name, outcome in outcomes.items())
        + ".",
        "",
        *_table(TARGET_COLUMNS, target_rows(found), {2}),
        "",
        *_table(("scenario", "figure", "median", "spread", "runs"), figure_rows(outcomes), {2, 3, 4}),
        "",
    ]
    return "\n".join(lines)


def as_json(meta: dict[str, Any], outcomes: dict[str, Outcome], found: list[Verdict]) -> dict[str, Any]:
    return {
        **meta,
        "scenarios": {
            name: {
                "what": outcome.scenario.what,
                "runs": {str(i): run for i, run in outcome.runs.items()},
                "medians": {f: statistics.median(outcome.values(f)) for f in outcome.figures()},
                "skipped": outcome.skipped,
                "errors": outcome.errors,
                "seconds": outcome.seconds,
            }
            for name, outcome in outcomes.items()
        },
        "targets": [
            {
                "scenario": v.scenario,
                "measures": v.measures,
                "target": v.target,
                "measured": v.measured,
                "met": v.met,
                "note": v.note,
            }
            for v in found
        ],
    }
