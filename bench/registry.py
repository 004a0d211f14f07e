"""Every scenario of the suite, in the order it runs (a new scenario is one more line here)."""

from __future__ import annotations

from bench import ingest, raw
from bench.scenario import Scenario, Target

#: Ingest against the raw broker's consume rate of the same run.
INGEST_TARGET = Target("end to end msg/s", 0.5, at_most=False, per=("raw", "consume msg/s"))

SCENARIOS: tuple[Scenario, ...] = (
    Scenario("raw", "raw broker: pika publish with pipelined confirms, aio-pika consume", raw.figures),
    Scenario("ingest", "robot events stored (SQLite) and acked", ingest.figures, (INGEST_TARGET,)),
    Scenario("ingest-mongodb", "the same with MongoDB", ingest.figures_mongodb, (INGEST_TARGET,)),
)


def by_name() -> dict[str, Scenario]:
    return {scenario.name: scenario for scenario in SCENARIOS}
