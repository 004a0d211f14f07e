"""Every scenario of the suite, in the order it runs (a new scenario is one more line here).

Each has a time budget per run (``budget_s``) on a quiet 2-core machine; the default run
(``python -m bench``: 3 runs, fewer where ``max_runs`` says) must fit in
:data:`DEFAULT_RUN_BUDGET_S` by those budgets, and tests/test_bench.py checks that it does.
"""

from __future__ import annotations

from collections.abc import Sequence

from bench import (
    api_logins,
    hazard_backlog,
    hazard_latency,
    ingest,
    map_transfer,
    outbox,
    raw,
    recorder,
    replay,
    worker_memory,
)
from bench.scenario import Scenario, Target

#: What the default run's budgets may add up to.
DEFAULT_RUN_BUDGET_S = 12 * 60
DEFAULT_RUNS = 3

#: Ingest against the raw broker's consume rate of the same run.
INGEST_TARGET = Target("end to end msg/s", 0.5, at_most=False, per=("raw", "consume msg/s"))

SCENARIOS: tuple[Scenario, ...] = (
    Scenario(
        "raw", "raw broker: pika publish with pipelined confirms, aio-pika consume", raw.figures, budget_s=5
    ),
    Scenario(
        "ingest", "robot events stored (SQLite) and acked", ingest.figures, (INGEST_TARGET,), budget_s=15
    ),
    Scenario(
        "ingest-mongodb", "the same with MongoDB", ingest.figures_mongodb, (INGEST_TARGET,), budget_s=15
    ),
    Scenario(
        "outbox",
        "the robot's outbox: append time at 0, 10,000 and 50,000 waiting events; drain after an outage",
        outbox.figures,
        (
            Target("append ms at 50,000, p99", 5, at_most=True, unit=" ms"),
            Target("drain msg/s", 0.5, at_most=False, per=("raw", "publish msg/s")),
        ),
        budget_s=10,
    ),
    Scenario(
        "hazard",
        f"explorer's hazard to the warden's receipt, {hazard_latency.RATE:,} telemetry events/s beside",
        hazard_latency.figures,
        (
            Target("hazard p50 ms", 5, at_most=True, unit=" ms"),
            Target("hazard p99 ms", 20, at_most=True, unit=" ms"),
        ),
        budget_s=15,
    ),
    Scenario(
        "hazard-backlog",
        f"hazards to two wardens while {hazard_backlog.ROBOTS} robots drain "
        f"{hazard_backlog.ROBOTS * hazard_backlog.PER_ROBOT:,} status events after an outage",
        hazard_backlog.figures,
        (Target("hazard p99 in raw hops", 10, at_most=True),),
        budget_s=25,
    ),
    # no target: one run, for comparison with hazard's
    Scenario(
        "hazard-idle",
        "the same with no telemetry beside",
        hazard_latency.figures_idle,
        max_runs=1,
        budget_s=15,
    ),
    Scenario(
        "hazard-recorder",
        "as hazard, with the recorder child",
        hazard_latency.figures_with_recorder,
        max_runs=1,
        budget_s=15,
    ),
    Scenario(
        "map",
        "a 4000 x 4000 PGM (16 MB) from the explorer's publish to a warden's identical copy",
        map_transfer.figures,
        (Target("transfer s", 2, at_most=True, unit=" s"),),
        budget_s=5,
    ),
    Scenario(
        "recorder",
        "`fleetbus recorder run` at 100 msg/s of 480 bytes: CPU share and resident memory",
        recorder.figures,
        (
            Target("recorder CPU %", 10, at_most=True, unit=" %"),
            Target("recorder RSS MB, peak", 80, at_most=True, unit=" MB"),
        ),
        budget_s=40,
    ),
    Scenario(
        "api-logins",
        f"`fleetbus api`: GET /users/me while {api_logins.LOGINS} clients log in at once",
        api_logins.figures,
        (Target(f"GET p99 ms, {api_logins.LOGINS} logging in", 50, at_most=True, unit=" ms"),),
        budget_s=15,
    ),
    Scenario(
        "memory",
        f"the worker's resident memory over {worker_memory.EVENTS:,} events "
        "(growth from a tenth of them to the end)",
        worker_memory.figures,
        (Target("growth %", 10, at_most=True, unit=" %"),),
        max_runs=1,
        budget_s=60,
    ),
    Scenario(
        "replay",
        f"`fleetbus replay --speed 0` of {replay.MESSAGES:,} recorded messages: its resident memory",
        replay.figures,
        (Target("replay RSS MB, peak", 150, at_most=True, unit=" MB"),),
        max_runs=1,
        budget_s=20,
    ),
)


def by_name() -> dict[str, Scenario]:
    return {scenario.name: scenario for scenario in SCENARIOS}


def budget(scenarios: Sequence[Scenario], runs: int) -> float:
    """Seconds the runs of ``scenarios`` may take by their budgets."""
    return sum(scenario.runs(runs) * scenario.budget_s for scenario in scenarios)
