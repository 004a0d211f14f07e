"""Failed logins, limited per account and per client address (moving windows, ``limits``).

- An account: ``FLEETBUS_API_ACCOUNT_FAILURES`` (5 per 5 minutes) failures to log in to it from
  one address, and that address gets 429 for that account until the oldest failure leaves the
  window. Counted per address, so that someone guessing elsewhere cannot lock the account's owner
  (an administrator, say) out; and never for good: the window moves on, ``Retry-After`` says when.
- An address: ``FLEETBUS_API_ADDRESS_FAILURES`` (20 per 5 minutes) failures to any accounts, and
  it gets 429 for every account: guessing across many accounts is slowed down too.

A refused attempt is answered before its password is checked, so it costs no hashing. No more
passwords are checked at once than the failures a window has room for: a login beyond that waits
for one under way to end, so that many logins sent at once cannot all pass the check before the
first failure is counted (and logins that succeed, sent at once, all go through). A login that
succeeds clears its account's count from that address. The counts live in the API process:
a restart clears them, and several replicas each count their own; a window with no failure left
in it is forgotten (:class:`ForgettingStorage`), so they take memory for the failures of the last
window only, and a name that no account can have is counted under one key, whatever its length.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import Counter
from collections.abc import AsyncIterator
from contextlib import AbstractAsyncContextManager, asynccontextmanager

from limits import RateLimitItem, parse
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter

from fleetbus.schemas.identity import NAME_PATTERN

#: How often (seconds, at most) failed logins look for windows to forget.
FORGET_EVERY_S = 60.0
#: The account key of a name no account can have (any length: it is the client's to choose).
NO_SUCH_NAME = "(not an account name)"


class TooManyFailures(Exception):
    """A login refused before its password is checked; ``retry_after`` is in whole seconds."""

    def __init__(self, detail: str, retry_after: int) -> None:
        super().__init__(detail)
        self.detail = detail
        self.retry_after = retry_after


class ForgettingStorage(MemoryStorage):
    """``limits``' memory storage, forgetting windows with no entry left in them.

    Its own expiry (limits 5.8) empties a moving window's list of expired entries but keeps the
    key for good: one for every address that ever failed a login, and one for every name it tried
    from there, kept as long as the process runs.
    """

    def forget_expired(self, now: float | None = None) -> int:
        """Forget the windows whose every entry has expired by ``now``; return how many."""
        now = time.time() if now is None else now
        forgotten = 0
        for key in list(self.events):
            with self.locks[key]:
                entries = self.events.get(key)
                if entries is not None and all(entry.expiry <= now for entry in entries):
                    del self.events[key]
                    forgotten += 1
            if key not in self.events:
                self.locks.pop(key, None)
        return forgotten

    def windows(self) -> int:
        """How many windows are kept."""
        return len(self.events)


class LoginLimits:
    def __init__(self, per_account: str, per_address: str) -> None:
        self.storage = ForgettingStorage()
        self._limiter = MovingWindowRateLimiter(self.storage)
        self._forgot_at = time.monotonic()
        self._per_account = parse(per_account)
        self._per_address = parse(per_address)
        self._checking: Counter[tuple[str, ...]] = Counter()
        """Attempts under way (their passwords being checked), by window key."""
        self._ended = asyncio.Condition()
        """Notified when an attempt under way ends."""

    def _windows(self, account: str, address: str) -> list[tuple[RateLimitItem, tuple[str, ...], str]]:
        name = account if NAME_PATTERN.fullmatch(account) else NO_SUCH_NAME
        return [
            (self._per_address, ("address", address), f"from {address}"),
            (self._per_account, ("account", name, address), f"to {name} from {address}"),
        ]

    async def begin(self, account: str, address: str) -> AbstractAsyncContextManager[None]:
        """A login attempt, to be used as a context while its password is checked. Raise
        :class:`TooManyFailures` when either limit is reached; wait while the attempts under way
        would reach it were they to fail (until one ends); then count this one among them until
        the context ends."""
        windows = self._windows(account, address)
        async with self._ended:  # held while looking, so that no end is missed before the wait
            while True:
                for limit, key, what in windows:
                    if not self._limiter.test(limit, *key):
                        reset = self._limiter.get_window_stats(limit, *key).reset_time
                        wait = max(1, math.ceil(reset - time.time()))
                        raise TooManyFailures(f"too many failed logins {what}; try again in {wait} s", wait)
                if all(self._room(limit, key) for limit, key, _ in windows):
                    break
                await self._ended.wait()
            keys = [key for _, key, _ in windows]
            self._checking.update(keys)
        return self._under_way(keys)

    def _room(self, limit: RateLimitItem, key: tuple[str, ...]) -> bool:
        """Whether one more attempt fits the window were every one under way to fail."""
        return self._limiter.test(limit, *key, cost=self._checking[key] + 1)

    @asynccontextmanager
    async def _under_way(self, keys: list[tuple[str, ...]]) -> AsyncIterator[None]:
        try:
            yield
        finally:
            self._checking -= Counter(keys)  # keeps the keys with attempts still under way only
            async with self._ended:
                self._ended.notify_all()

    def failed(self, account: str, address: str) -> None:
        for limit, key, _ in self._windows(account, address):
            self._limiter.hit(limit, *key)
        if time.monotonic() - self._forgot_at >= FORGET_EVERY_S:
            self._forgot_at = time.monotonic()
            self.storage.forget_expired()

    def succeeded(self, account: str, address: str) -> None:
        [_, (_, key, _)] = self._windows(account, address)
        self._limiter.clear(self._per_account, *key)
