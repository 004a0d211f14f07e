"""The broker's message rates over the last hour, from the management API's samples of the
service's virtual host: how many messages a second were published to it and delivered from it.

The management API keeps each counter's cumulative value at regular moments (one a minute for an
hour, by its default retention policy); a rate is the difference between two neighbouring
samples over the time between them. A counter that went down (the broker restarted) starts again
from zero at that sample."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
from itertools import pairwise
from typing import Any

#: The window charted, and the time between two samples (the broker's default retention keeps
#: one a minute for an hour).
AGE_S = 3600
EVERY_S = 60
#: The rates charted: the management API's counter, and what the chart calls it.
RATES = {"publish": "published to fleetbus", "deliver_get": "delivered to consumers"}

Span = tuple[datetime, datetime, float]


@dataclass(frozen=True)
class Rates:
    """Each counter's rate (messages a second) between neighbouring samples, oldest first."""

    spans: dict[str, list[Span]]

    def newest(self, counter: str) -> float | None:
        found = self.spans.get(counter)
        return found[-1][2] if found else None


def rates_of(vhost: dict[str, Any]) -> Rates:
    """The rates in a ``vhost_rate_samples`` answer. A counter the broker has no samples of while
    it has others (nothing delivered yet) is a rate of zero at their moments; with no samples at
    all (no traffic yet), there are none."""
    stats = vhost.get("message_stats") or {}
    sampled = {counter: _samples(stats, counter) for counter in RATES}
    moments = next((sorted(t for t, _ in found) for found in sampled.values() if found), [])
    spans: dict[str, list[Span]] = {}
    for counter, ordered in sampled.items():
        ordered = ordered or [(t, 0.0) for t in moments]
        found: list[Span] = []
        for (t0, c0), (t1, c1) in pairwise(ordered):
            if t1 <= t0:
                continue
            grown = c1 - c0 if c1 >= c0 else c1  # a restart counts from zero again
            found.append((_moment(t0), _moment(t1), grown / ((t1 - t0) / 1000)))
        spans[counter] = found
    return Rates(spans)


def _samples(stats: dict[str, Any], counter: str) -> list[tuple[int, float]]:
    """The counter's samples, oldest first: (milliseconds since the epoch, cumulative count)."""
    samples = (stats.get(f"{counter}_details") or {}).get("samples") or []
    return sorted((int(s["timestamp"]), float(s["sample"])) for s in samples if "timestamp" in s)


def _moment(ms: int) -> datetime:
    return datetime.fromtimestamp(ms / 1000, timezone.utc)
