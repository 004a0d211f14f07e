"""``bench.site_latency`` with tiny numbers: it drives every phase on a real pair and reports it
(its speed is the bench's to measure, not asserted here)."""

from __future__ import annotations

import math

from bench import site_latency
from tests.sites.pair import SitePair


def test_the_site_latency_bench_measures_the_link_up_cut_and_restored(pair: SitePair) -> None:
    found, telemetry = site_latency.measure(pair, count=3, rate=50, rounds=1)
    assert list(found) == list(site_latency.PHASES) and telemetry > 0
    for name, phase in found.items():
        assert len(phase.hazard_ms) == len(phase.ping_ms) == 3, name
        assert all(math.isfinite(value) for value in phase.figures().values()), name
    assert found["cut"].waiting_after[0] >= 3, "the cut's hazards wait in the uplink for central"
    assert pair.uplink_waiting() == 0 and pair.uplink_state() == "running", "restored and drained"
    assert {"cut / up, hazard p99", "restored / up, hazard p50"} <= site_latency.ratios(found).keys()
    site_latency.table(found, "tiny")
