"""``fleetbus demo``: the whole core loop with real parts, summarised as a table."""

from __future__ import annotations

from typing import Annotated

import typer

from fleetbus.cli.context import console, endpoint, fail, settings
from fleetbus_dev.demo import report_table, run_demo, steps_table


def demo(
    hazards: Annotated[int, typer.Option(help="hazards detected after the wardens localised")] = 18,
    telemetry: Annotated[int, typer.Option(help="status messages the explorer sends")] = 20,
    map_size: Annotated[int, typer.Option(help="width and height of the map, in pixels")] = 2000,
) -> None:
    """An explorer, two wardens and a guide: held hazards, claims, a map transfer, beacons."""
    report = run_demo(
        settings(), endpoint(), console, hazards=hazards, telemetry=telemetry, map_size=map_size
    )
    console.print(steps_table(report))
    console.print(report_table(report))
    expected = report.published.get("hazard", 0) + report.published.get("map", 0)
    lost = [w for w, got in report.delivered.items() if sum(got.values()) != expected]
    if not report.ok or report.stored != report.published or lost:
        fail("the demo did not end as it should (see the tables)")
