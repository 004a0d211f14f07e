"""The project's one backoff policy: how long to wait before trying again after a failure.

The bound of the wait doubles with each failure in a row, from ``initial`` up to ``maximum``.
Server-side retries (:mod:`fleetbus.broker.retry`, on tenacity) wait that bound plus up to
``jitter`` seconds at random; the robot's reconnects draw their wait uniformly between 0 and the
bound ("full jitter"). After a broker restart every robot of the team lost its connection at the
same moment: with a fixed schedule (0.1 s, 0.2 s, 0.4 s, ...) they would all try again at the
same moments, in lockstep, and hit the broker together each time; full jitter spreads the team's
attempts over the whole window ("Exponential Backoff And Jitter", AWS Architecture Blog).

It lives here, in plain Python, because the robot's install is only pika, tinydb, pydantic and
pyyaml; the workers' tenacity waits are built from it.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

#: The bound of the robot's first wait; it doubles with each attempt that fails in a row, up to the cap.
FIRST_DELAY = 0.1


@dataclass(frozen=True)
class Backoff:
    """How long to wait before each retry: ``initial`` doubling up to ``maximum``, plus up to
    ``jitter`` seconds at random (so that many clients do not retry in step)."""

    initial: float = 0.1
    maximum: float = 5.0
    jitter: float = 0.1

    def bound(self, failures: int) -> float:
        """The exponential bound after ``failures`` failures in a row (0: before the first retry)."""
        return min(self.maximum, self.initial * 2.0 ** min(failures, 64))

    def delay(self, failures: int) -> float:
        """The bound plus up to ``jitter`` seconds at random."""
        return self.bound(failures) + random.uniform(0.0, self.jitter)


def reconnect_delay(attempt: int, cap: float, first: float = FIRST_DELAY) -> float:
    """The robot's wait before try ``attempt + 1`` after ``attempt`` failures in a row (0: the first
    failure): uniform between 0 and the bound of ``Backoff(first, cap)`` (full jitter)."""
    return random.uniform(0.0, Backoff(first, cap).bound(attempt))
