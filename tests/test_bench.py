"""The benchmark suite runs, checks what it measured, and reports it: no speed is asserted here."""

from __future__ import annotations

import importlib
import io
import json
import math
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from pymongo import MongoClient
from rich.console import Console
from rich.progress import Progress

from bench import ingest, scaling, suite
from bench.profile import PROJECT_ROOT, busiest
from bench.registry import DEFAULT_RUN_BUDGET_S, DEFAULT_RUNS, SCENARIOS, budget, by_name
from bench.report import Outcome, as_json, markdown, verdicts
from bench.scenario import Context, Figures, Scenario, Skip, Target
from bench.suite import main, run, select
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from tests.store.test_contract import LATER, record
from tests.support import Bus, printed_until

RAW = Scenario("raw", "raw", lambda context: {"consume msg/s": 1000.0})


class Tiny(Context):
    """Every scenario at a fiftieth of its ``--quick`` size (at least 2): does it work, not how fast."""

    def size(self, full: int, quick: int) -> int:
        return max(2, quick // 50)


@pytest.fixture
def progress() -> Iterator[Progress]:
    with Progress(console=Console(file=io.StringIO())) as bar:
        yield bar


@pytest.fixture
def tiny(endpoint: BrokerEndpoint, management: ManagementAPI) -> Tiny:
    return Tiny(endpoint, management)


def outcome(scenario: Scenario, runs: dict[int, Figures], **kwargs: object) -> Outcome:
    return Outcome(scenario, 3, runs, **kwargs)  # type: ignore[arg-type]


def test_a_ratio_target_pairs_each_run_with_the_baseline_run_of_the_same_number() -> None:
    target = Target("msg/s", 0.5, at_most=False, per=("raw", "consume msg/s"))
    runs = {0: {"msg/s": 400.0}, 1: {"msg/s": 900.0}, 2: {"msg/s": 2000.0}}
    baseline = {0: {"consume msg/s": 1000.0}, 2: {"consume msg/s": 4000.0}}  # run 1 of raw failed
    assert target.value(runs, baseline) == pytest.approx((0.4 + 0.5) / 2)
    assert target.met(0.5) and not target.met(0.49)
    assert Target("p99 ms", 20, at_most=True).met(19.9) and not Target("p99 ms", 20, at_most=True).met(20)


def test_verdicts_say_why_a_target_was_not_measured() -> None:
    per_raw = Target("msg/s", 0.5, at_most=False, per=("raw", "consume msg/s"))
    ingest_ = Scenario("ingest", "", lambda context: {}, (per_raw,))
    mongo = Scenario("ingest-mongodb", "", lambda context: {}, (per_raw,))
    latency = Scenario("hazard", "", lambda context: {}, (Target("p99 ms", 20, at_most=True, unit=" ms"),))
    outcomes = {
        "raw": outcome(RAW, {0: {"consume msg/s": 1000.0}}),
        "ingest": outcome(ingest_, {0: {"msg/s": 450.0}}),
        "ingest-mongodb": outcome(mongo, {}, skipped="FLEETBUS_MONGODB_URL is unset"),
        "hazard": outcome(latency, {}, errors=["TimeoutError: 3 arrivals"]),
    }
    found = {v.scenario: v for v in verdicts(outcomes)}
    assert (found["ingest"].measured, found["ingest"].met) == (0.45, False)
    assert (
        found["ingest-mongodb"].met is None
        and "FLEETBUS_MONGODB_URL is unset" in found["ingest-mongodb"].note
    )
    assert found["hazard"].met is None and "TimeoutError: 3 arrivals" in found["hazard"].note
    assert [v.met for v in verdicts({"ingest": outcomes["ingest"]})] == [None]  # raw was not run
    text = markdown(
        {"finished": "now", "seconds": 60, "command": "x", "machine": _machine(), "load at the end": "x"},
        outcomes,
        list(found.values()),
    )
    assert "| ingest | msg/s ÷ raw consume msg/s | 0.45 | ≥ 0.5 | **no** |" in text
    assert (
        "| hazard | p99 ms |  | < 20 ms | not measured (1 of 3 runs failed: TimeoutError: 3 arrivals) |"
        in text
    )


def test_selecting_a_scenario_adds_the_one_its_targets_compare_with() -> None:
    assert [s.name for s in select("ingest")] == ["raw", "ingest"]
    assert [s.name for s in select("map,raw")] == ["raw", "map"]  # the registry's order
    with pytest.raises(SystemExit, match="unknown scenario nope; known: raw, ingest"):
        select("nope,raw")


def test_a_failing_scenario_is_reported_and_the_others_still_run(tiny: Tiny, progress: Progress) -> None:
    calls: list[int] = []

    def flaky(context: Context) -> Figures:
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("the broker went away")
        return {"x": 1.0}

    def absent(context: Context) -> Figures:
        raise Skip("no such thing here")

    scenarios = [
        Scenario("flaky", "", flaky),
        Scenario("absent", "", absent),
        Scenario("once", "", lambda context: {"y": 2.0}, max_runs=1),
    ]
    outcomes = run(scenarios, tiny, 3, progress)
    assert sorted(outcomes["flaky"].runs) == [0, 2]
    assert outcomes["flaky"].errors == ["RuntimeError: the broker went away"]
    assert outcomes["absent"].skipped == "no such thing here" and not outcomes["absent"].runs
    assert list(outcomes["once"].runs) == [0]
    assert progress.tasks[0].completed == progress.tasks[0].total == 3 + 3 + 1


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda scenario: scenario.name)
def test_every_scenario_runs_against_the_real_broker_and_checks_what_it_measured(
    scenario: Scenario, tiny: Tiny, progress: Progress, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each scenario checks its own result (every event stored once and acked, the map identical);
    it runs with those its targets compare with, as ``--only`` runs it (one test each: in parallel)."""
    monkeypatch.delenv("FLEETBUS_MONGODB_URL", raising=False)
    scenarios = [s for s in SCENARIOS if s.name in {scenario.name, *scenario.needs}]
    outcomes = run(scenarios, tiny, 1, progress)
    assert {name: o.errors for name, o in outcomes.items() if o.errors} == {}
    for name, found in outcomes.items():
        if name == "ingest-mongodb":
            assert found.skipped is not None and "FLEETBUS_MONGODB_URL is unset" in found.skipped
            continue
        figures = found.runs[0]
        assert all(math.isfinite(value) for value in figures.values()), name
        assert {t.figure for t in found.scenario.targets} <= figures.keys(), name
    if scenario.name == "hazard":
        assert outcomes["hazard"].runs[0]["telemetry events/s"] > 0
    report = as_json({}, outcomes, verdicts(outcomes))
    assert len(report["targets"]) == sum(len(s.targets) for s in scenarios)
    json.dumps(report)  # plain JSON


def test_ingest_on_mongodb_runs_in_a_database_of_its_own(
    tiny: Tiny, mongodb_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FLEETBUS_MONGODB_URL", mongodb_url)
    figures = ingest.figures_mongodb(tiny)
    assert figures.keys() == {"end to end msg/s", "drain msg/s"}
    with MongoClient(mongodb_url, serverSelectionTimeoutMS=5000) as client:
        assert not [name for name in client.list_database_names() if name.startswith("bench_")]
    monkeypatch.delenv("FLEETBUS_MONGODB_URL")
    with pytest.raises(Skip, match="FLEETBUS_MONGODB_URL is unset"):
        ingest.figures_mongodb(tiny)


def test_the_command_writes_json_and_markdown(endpoint: BrokerEndpoint, tmp_path: Path) -> None:
    assert main(["--only", "raw", "--runs", "2", "--quick", "--out", str(tmp_path)]) == 0
    (written,) = tmp_path.glob("suite-*.json")
    report = json.loads(written.read_text())
    assert report["runs"] == 2 and report["quick"] is True
    assert sorted(report["scenarios"]["raw"]["runs"]) == ["0", "1"]
    assert report["command"] == ".venv/bin/python -m bench --only raw --runs 2 --quick --out " + str(tmp_path)
    table = written.with_suffix(".md").read_text()
    assert "| raw | consume msg/s |" in table and report["machine"]["cpu"] in table


def test_stopped_by_sigterm_the_suite_writes_the_runs_measured_so_far(
    endpoint: BrokerEndpoint, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[int] = []

    def measure(context: Context) -> Figures:
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGTERM)  # as a CI job's timeout stops it
        return {"consume msg/s": 1000.0}

    stopped = Scenario("raw", "raw", measure)
    monkeypatch.setattr(suite, "SCENARIOS", (stopped,))
    monkeypatch.setattr(suite, "by_name", lambda: {"raw": stopped})
    handler = signal.getsignal(signal.SIGTERM)
    assert main(["--only", "raw", "--runs", "3", "--out", str(tmp_path)]) == 1
    assert signal.getsignal(signal.SIGTERM) is handler, "the suite's handler ends with it"
    (written,) = tmp_path.glob("suite-*.json")
    report = json.loads(written.read_text())["scenarios"]["raw"]
    assert sorted(report["runs"]) == ["0"] and report["errors"] == ["interrupted"]


#: The suite as ``python -m bench`` runs it, on two scenarios: one that reports at once, then one
#: that waits for a signal (as a long measurement would be stopped in the middle).
STOPPED_SUITE = """
import signal, sys
from bench import suite
from bench.scenario import Scenario

def blocked(context):
    context.show("waiting to be stopped")
    signal.pause()
    return {}

scenarios = (
    Scenario("raw", "raw", lambda context: {"consume msg/s": 1000.0}),
    Scenario("blocked", "waits", blocked),
)
suite.SCENARIOS = scenarios
suite.by_name = lambda: {scenario.name: scenario for scenario in scenarios}
sys.exit(suite.main(["--runs", "1", "--out", sys.argv[1]]))
"""


def test_a_suite_process_stopped_by_sigterm_writes_what_it_measured(bus: Bus, tmp_path: Path) -> None:
    """A real process, as a CI job's timeout or a supervisor stops it: SIGTERM once a scenario has
    reported, in the middle of the next one."""
    process = subprocess.Popen(
        [sys.executable, "-c", STOPPED_SUITE, str(tmp_path)],
        cwd=PROJECT_ROOT,
        env={**bus.worker_env(), "PYTHONUNBUFFERED": "1", "COLUMNS": "200"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        # the wait is for a line: generous, for a loaded machine whose management API answers late
        seen = "".join(printed_until(process, "run 1/1 raw: ", 240))
        process.send_signal(signal.SIGTERM)
        out, _ = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 1, seen + out
    assert "run 1/1 blocked interrupted: reporting the runs done so far" in out, out
    (written,) = tmp_path.glob("suite-*.json")
    report = json.loads(written.read_text())["scenarios"]
    assert report["raw"]["runs"] == {"0": {"consume msg/s": 1000.0}} and report["raw"]["errors"] == []
    assert report["blocked"]["runs"] == {} and report["blocked"]["errors"] == ["interrupted"]
    assert "| raw | consume msg/s | 1,000 |" in written.with_suffix(".md").read_text()
    assert "the suite took" in out, out


def test_the_default_run_fits_in_its_time_by_the_budgets() -> None:
    assert budget(SCENARIOS, DEFAULT_RUNS) <= DEFAULT_RUN_BUDGET_S
    assert all(scenario.budget_s > 0 for scenario in SCENARIOS)


def test_the_registry_names_are_unique_and_every_baseline_exists() -> None:
    assert len(by_name()) == len(SCENARIOS)
    for scenario in SCENARIOS:
        for target in scenario.targets:
            if target.per:
                assert target.per[0] in by_name(), (scenario.name, target.per)


def test_a_profile_is_summed_up_by_package_per_thread(tmp_path: Path) -> None:
    files = [
        ".venv/lib/python3.11/site-packages/aiormq/connection.py",
        "/usr/lib/python3.11/asyncio/events.py",
    ]
    frames = [
        {"name": "f", "file": file, "line": 1} for file in [*files, str(PROJECT_ROOT / "workers/ingest.py")]
    ]
    threads = [
        {
            "type": "sampled",
            "name": "MainThread",
            "samples": [[1, 0], [1, 0], [1, 2], [1]],
            "weights": [0.1] * 4,
        },
        {"type": "sampled", "name": "sqlite", "samples": [[2]], "weights": [0.1]},
    ]
    path = tmp_path / "worker.speedscope.json"
    path.write_text(json.dumps({"shared": {"frames": frames}, "profiles": threads}))
    (main_thread, seconds, packages), (other, _, other_packages) = busiest(path)
    assert (main_thread, other) == ("MainThread", "sqlite")
    assert seconds == pytest.approx(0.4)
    assert [(name, round(share, 2)) for name, share in packages] == [
        ("aiormq", 0.5),
        ("workers", 0.25),
        ("asyncio", 0.25),
    ]
    assert other_packages == [("workers", 1.0)]


def _machine() -> dict[str, str]:
    return {key: key for key in ("cpu", "memory", "os", "python", "broker", "load")}


@pytest.mark.parametrize(
    "module", sorted(path.stem for path in (PROJECT_ROOT / "bench").glob("*.py") if path.stem != "__main__")
)
def test_every_benchmark_module_imports(module: str) -> None:
    """Modules run only by hand (``python -m bench.scaling``) break silently otherwise."""
    importlib.import_module(f"bench.{module}")


def test_the_scaling_probe_refuses_a_count_or_an_order_that_is_off(bus: Bus) -> None:
    """What ``bench.scaling`` checks after every run: exactly the events published, each robot's
    stored in the order it published them (a later number never stored before an earlier one)."""
    t0 = datetime(2026, 11, 24, 8, 0, tzinfo=timezone.utc)
    in_order = [record("robot1", seq, "status", t0 + timedelta(seconds=seq)) for seq in range(3)]
    bus.with_store(lambda store: store.events.write_events(in_order))
    probe = scaling.Probe(bus.settings)
    try:
        probe.verify(3, "in order")
        with pytest.raises(AssertionError, match="stored 3 events, not 4"):
            probe.verify(4, "one missing")
        another_run = record("robot1", 0, "status", t0, epoch=LATER)  # numbers apart from the first
        bus.with_store(lambda store: store.events.write_events([another_run]))
        probe.verify(4, "two runs of one robot")
        overtaking = record("robot2", 1, "status", t0)  # stored before robot2's seq 0
        earlier = record("robot2", 0, "status", t0 + timedelta(seconds=1))  # but arriving after it
        bus.with_store(lambda store: store.events.write_events([overtaking, earlier]))
        with pytest.raises(AssertionError, match=r"of robot2 \(epoch \S+\) was stored before an earlier"):
            probe.verify(6, "overtaken")
    finally:
        probe.close()
