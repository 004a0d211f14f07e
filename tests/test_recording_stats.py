"""fleetbus stats: the recording's growth and insert rate, from the recorder's own samples."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from fleetbus.schemas.routing import EventType
from fleetbus.workers.recorder.growth import growth
from fleetbus.workers.store.recordings import StorageSample
from tests.factories import status
from tests.support import Bus, wait_for
from tests.test_cli import fleetbus

T0 = datetime(2021, 6, 1, 18, 0, tzinfo=timezone.utc)


def test_the_recorder_samples_the_database_and_stats_reads_the_rates(bus: Bus, tmp_path: Path) -> None:
    robot = bus.add("stats-robot")
    with bus.recorder(sample_interval=0.2) as recorder, bus.robot(robot) as client:
        client.publish_many([(EventType.STATUS, status(float(i))) for i in range(40)])
        wait_for(lambda: recorder.stats().recorded == 40, what="the first burst recorded")
        client.publish_many([(EventType.STATUS, status(float(i))) for i in range(20)])
        wait_for(lambda: recorder.stats().recorded == 60, what="the second burst recorded")
    # the recorder's last sample, on stopping, counts what it inserted since the one before
    result = fleetbus(bus, "stats", "--since", "10m", "--every", "1s", "--json")
    assert result.returncode == 0, result.stderr
    rows = [json.loads(line) for line in result.stdout.splitlines()]
    assert sum(row["inserted"] for row in rows) == 60
    assert rows[-1]["database_bytes"] > 60 * 100
    for row in rows:
        assert row["inserts_per_minute"] == pytest.approx(row["inserted"] / row["seconds"] * 60)
    plot = tmp_path / "growth.png"
    table = fleetbus(bus, "stats", "--since", "10m", "--plot", str(plot))
    assert "inserts per minute" in table.stdout and f"wrote {plot}" in table.stdout.replace("\n", "")
    assert plot.read_bytes()[:4] == b"\x89PNG"


def test_rates_from_samples_of_one_or_two_recorders() -> None:
    def at(seconds: float) -> datetime:
        return T0 + timedelta(seconds=seconds)

    samples = [
        StorageSample(at(0), "a", 1_000_000, 0),
        StorageSample(at(60), "a", 4_000_000, 600),
        StorageSample(at(90), "b", 4_000_000, 0),  # a standby recorder: same database, inserts nothing
        StorageSample(at(120), "a", 5_000_000, 300),
        StorageSample(at(150), "b", 5_500_000, 0),
        StorageSample(at(180), "a", 5_500_000, 100),
    ]
    per_minute = growth(samples, timedelta(minutes=1))
    assert [(g.seconds, g.grown_bytes, g.inserted) for g in per_minute] == [
        (90, 3_000_000, 600),  # from the sample before the bucket to its last one
        (60, 1_500_000, 300),
        (30, 0, 100),
    ]
    assert (per_minute[0].megabytes_per_minute, per_minute[0].inserts_per_minute) == (2.0, 400)
    [first, second] = growth(samples, timedelta(minutes=2))
    assert (first.seconds, first.grown_bytes, first.inserted, first.database_bytes) == (
        90,
        3_000_000,
        600,
        4_000_000,
    )
    assert (second.seconds, second.grown_bytes, second.inserted) == (90, 1_500_000, 400)
