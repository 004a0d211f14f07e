"""Failed logins, limited per account and per client address (moving windows, ``limits``).

- An account: ``FLEETBUS_API_ACCOUNT_FAILURES`` (5 per 5 minutes) failures to log in to it from
  one address, and that address gets 429 for that account until the oldest failure leaves the
  window. Counted per address, so that someone guessing elsewhere cannot lock the account's owner
  (an administrator, say) out; and never for good: the window moves on, ``Retry-After`` says when.
- An address: ``FLEETBUS_API_ADDRESS_FAILURES`` (20 per 5 minutes) failures to any accounts, and
  it gets 429 for every account: guessing across many accounts is slowed down too.

A refused attempt is answered before its password is checked, so it costs no hashing. A login
that succeeds clears its account's count from that address. The counts live in the API process:
a restart clears them, and several replicas each count their own.
"""

from __future__ import annotations

import math
import time

from limits import RateLimitItem, parse
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter


class TooManyFailures(Exception):
    """A login refused before its password is checked; ``retry_after`` is in whole seconds."""

    def __init__(self, detail: str, retry_after: int) -> None:
        super().__init__(detail)
        self.detail = detail
        self.retry_after = retry_after


class LoginLimits:
    def __init__(self, per_account: str, per_address: str) -> None:
        self._limiter = MovingWindowRateLimiter(MemoryStorage())
        self._per_account = parse(per_account)
        self._per_address = parse(per_address)

    def _windows(self, account: str, address: str) -> list[tuple[RateLimitItem, tuple[str, ...], str]]:
        return [
            (self._per_address, ("address", address), f"from {address}"),
            (self._per_account, ("account", account, address), f"to {account} from {address}"),
        ]

    def check(self, account: str, address: str) -> None:
        """Raise :class:`TooManyFailures` when either limit is reached."""
        for limit, key, what in self._windows(account, address):
            if not self._limiter.test(limit, *key):
                reset = self._limiter.get_window_stats(limit, *key).reset_time
                wait = max(1, math.ceil(reset - time.time()))
                raise TooManyFailures(f"too many failed logins {what}; try again in {wait} s", wait)

    def failed(self, account: str, address: str) -> None:
        for limit, key, _ in self._windows(account, address):
            self._limiter.hit(limit, *key)

    def succeeded(self, account: str, address: str) -> None:
        self._limiter.clear(self._per_account, "account", account, address)
