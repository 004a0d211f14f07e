"""How long the robot waits before it tries the broker again: exponential, full jitter, capped.

After a broker restart every robot of the team lost its connection at the same moment. With a
fixed schedule (0.1 s, 0.2 s, 0.4 s, ...) they would all try again at the same moments, in
lockstep, and hit the broker together each time. Full jitter draws each wait uniformly between
0 and the exponential bound (itself capped), which spreads the team's attempts over the whole
window ("Exponential Backoff And Jitter", AWS Architecture Blog).

A small function of its own rather than tenacity, which the workers use for their retries: the
robot's install is only pika, tinydb, pydantic and pyyaml.
"""

from __future__ import annotations

import random

#: The bound of the first wait; it doubles with each attempt that fails in a row, up to the cap.
FIRST_DELAY = 0.1


def reconnect_delay(attempt: int, cap: float, first: float = FIRST_DELAY) -> float:
    """The wait before try ``attempt + 1`` after ``attempt`` failures in a row (0: the first failure):
    uniform between 0 and ``min(cap, first * 2**attempt)``."""
    bound = min(cap, first * 2.0 ** min(attempt, 64))
    return random.uniform(0.0, bound)
