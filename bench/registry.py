"""Every scenario of the suite, in the order it runs (a new scenario is one more line here)."""

from __future__ import annotations

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

#: Ingest against the raw broker's consume rate of the same run.
INGEST_TARGET = Target("end to end msg/s", 0.5, at_most=False, per=("raw", "consume msg/s"))

SCENARIOS: tuple[Scenario, ...] = (
    Scenario("raw", "raw broker: pika publish with pipelined confirms, aio-pika consume", raw.figures),
    Scenario("ingest", "robot events stored (SQLite) and acked", ingest.figures, (INGEST_TARGET,)),
    Scenario("ingest-mongodb", "the same with MongoDB", ingest.figures_mongodb, (INGEST_TARGET,)),
    Scenario(
        "outbox",
        "the robot's outbox: append time at 0, 10,000 and 50,000 waiting events; drain after an outage",
        outbox.figures,
        (
            Target("append ms at 50,000, p99", 5, at_most=True, unit=" ms"),
            Target("drain msg/s", 0.5, at_most=False, per=("raw", "publish msg/s")),
        ),
    ),
    Scenario(
        "hazard",
        f"explorer's hazard to the warden's receipt, {hazard_latency.RATE:,} telemetry events/s beside",
        hazard_latency.figures,
        (
            Target("hazard p50 ms", 5, at_most=True, unit=" ms"),
            Target("hazard p99 ms", 20, at_most=True, unit=" ms"),
        ),
    ),
    Scenario(
        "hazard-backlog",
        f"hazards to two wardens while {hazard_backlog.ROBOTS} robots drain "
        f"{hazard_backlog.ROBOTS * hazard_backlog.PER_ROBOT:,} status events after an outage",
        hazard_backlog.figures,
        (Target("hazard p99 in raw hops", 10, at_most=True),),
    ),
    Scenario("hazard-idle", "the same with no telemetry beside", hazard_latency.figures_idle),
    Scenario("hazard-recorder", "as hazard, with the recorder child", hazard_latency.figures_with_recorder),
    Scenario(
        "map",
        "a 4000 x 4000 PGM (16 MB) from the explorer's publish to a warden's identical copy",
        map_transfer.figures,
        (Target("transfer s", 2, at_most=True, unit=" s"),),
    ),
    Scenario(
        "recorder",
        "`fleetbus recorder run` at 100 msg/s of 480 bytes: CPU share and resident memory",
        recorder.figures,
        (
            Target("recorder CPU %", 10, at_most=True, unit=" %"),
            Target("recorder RSS MB, peak", 80, at_most=True, unit=" MB"),
        ),
    ),
    Scenario(
        "api-logins",
        f"`fleetbus api`: GET /users/me while {api_logins.LOGINS} clients log in at once",
        api_logins.figures,
        (Target(f"GET p99 ms, {api_logins.LOGINS} logging in", 50, at_most=True, unit=" ms"),),
    ),
    Scenario(
        "memory",
        "the worker's resident memory over 1,000,000 events (growth from a tenth of them to the end)",
        worker_memory.figures,
        (Target("growth %", 10, at_most=True, unit=" %"),),
        max_runs=1,
    ),
    Scenario(
        "replay",
        "`fleetbus replay --speed 0` of 1,000,000 recorded messages: its resident memory",
        replay.figures,
        (Target("replay RSS MB, peak", 150, at_most=True, unit=" MB"),),
        max_runs=1,
    ),
)


def by_name() -> dict[str, Scenario]:
    return {scenario.name: scenario for scenario in SCENARIOS}
