"""``fleetbus demo``: the whole core loop with real parts, summarised as a table."""

from __future__ import annotations

from typing import Annotated

import typer

from fleetbus.context import console, endpoint, fail, settings
from fleetbus.demo import report_table, run_demo


def demo(
    hazards: Annotated[int, typer.Option(help="hazards the explorer detects")] = 20,
    telemetry: Annotated[int, typer.Option(help="status messages the explorer sends")] = 20,
) -> None:
    """Explorer publishes hazards, telemetry and a map; two wardens receive the notifications."""
    report = run_demo(settings(), endpoint(), console, hazards=hazards, telemetry=telemetry)
    console.print(report_table(report))
    expected = report.published.get("hazard", 0) + report.published.get("map", 0)
    lost = [w for w, got in report.delivered.items() if sum(got.values()) != expected]
    if report.stored != report.published or lost:
        fail("the demo did not end with everything stored and delivered (see the table)")
