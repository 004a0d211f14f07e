"""What the suite runs: scenarios, each measuring named figures per run, and the targets on them."""

from __future__ import annotations

import statistics
import tempfile
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from fleetbus.broker.accounts import fresh_vhost
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from tests.support import Bus, fresh_bus

Figures = dict[str, float]
"""One run's measurements, by name; the name carries the unit (``consume msg/s``, ``p99 ms``)."""


class Skip(Exception):
    """The scenario cannot run here; the message says why (it is reported, not hidden)."""


@dataclass
class Context:
    """What a scenario gets: the broker, the run's size, and a line on the progress bar."""

    endpoint: BrokerEndpoint
    api: ManagementAPI
    quick: bool = False
    show: Callable[[str], None] = field(default=lambda text: None)
    """Say what the run is doing now (on the progress bar)."""

    def size(self, full: int, quick: int) -> int:
        return quick if self.quick else full

    @contextmanager
    def vhost(self) -> Iterator[str]:
        """The administrator's URL on a new, empty virtual host, deleted afterwards."""
        name = f"bench-{uuid.uuid4().hex[:10]}"
        try:
            yield fresh_vhost(self.api, self.endpoint.amqp_url, name)
        finally:
            self.api.delete_vhost(name)

    @contextmanager
    def bus(self, mongodb_url: str | None = None) -> Iterator[Bus]:
        """A virtual host, data folder and store of the run's own (SQLite, or ``mongodb_url``)."""
        with (
            tempfile.TemporaryDirectory(prefix="fleetbus-bench-") as folder,
            fresh_bus(self.endpoint, self.api, Path(folder), prefix="bench") as bus,
        ):
            if mongodb_url is not None:
                bus.settings = bus.settings.updated(mongodb_url=mongodb_url)
            yield bus


@dataclass(frozen=True)
class Target:
    """A figure's median must stay below (``at_most``) or reach ``limit``.

    With ``per`` (scenario, figure), the target is on the ratio of the figure to that one, taken
    run by run, both measured in the same run of the suite: a ratio to the raw broker holds
    across machines where absolute rates do not.
    """

    figure: str
    limit: float
    at_most: bool
    unit: str = ""
    per: tuple[str, str] | None = None

    def measures(self) -> str:
        """What is compared: the figure, or the ratio of the figure to the baseline's."""
        return self.figure if self.per is None else f"{self.figure} ÷ {self.per[0]} {self.per[1]}"

    def describe(self) -> str:
        """The limit: ``< 20 ms``, ``≥ 0.5``."""
        return f"{'<' if self.at_most else '≥'} {self.limit:g}{self.unit}"

    def value(self, runs: Mapping[int, Figures], baseline: Mapping[int, Figures] | None = None) -> float:
        """The median over the runs (by the suite's run number) of the figure, or of the ratio."""
        if self.per is None:
            return statistics.median(run[self.figure] for run in runs.values())
        assert baseline is not None
        paired = sorted(runs.keys() & baseline.keys())  # run i with the baseline's run i
        if not paired:
            raise ValueError(f"no run of {self.per[0]} to compare {self.figure} with")
        return statistics.median(runs[i][self.figure] / baseline[i][self.per[1]] for i in paired)

    def met(self, value: float) -> bool:
        return value < self.limit if self.at_most else value >= self.limit


@dataclass(frozen=True)
class Scenario:
    name: str
    what: str
    """One line: what it measures."""
    measure: Callable[[Context], Figures]
    """One run."""
    targets: tuple[Target, ...] = ()
    max_runs: int | None = None
    """Fewer runs than the suite's ``--runs`` (a scenario that takes minutes, or one with no target)."""
    budget_s: float = 60.0
    """What one run may take on a quiet 2-core machine; the suite says which runs took longer,
    and the default run's budgets add up to less than :data:`bench.registry.DEFAULT_RUN_BUDGET_S`."""

    @property
    def needs(self) -> tuple[str, ...]:
        """Scenarios whose figures its targets compare with."""
        return tuple(dict.fromkeys(t.per[0] for t in self.targets if t.per is not None))

    def runs(self, asked: int) -> int:
        return asked if self.max_runs is None else min(asked, self.max_runs)
