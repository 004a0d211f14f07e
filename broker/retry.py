"""The project's one retry helper for transient failures, on tenacity.

Waits follow the one backoff policy, :class:`fleetbus.publishers.backoff.Backoff` (exponential,
capped, with jitter; the robot's client uses it without tenacity); an optional deadline after
which the last error is raised as :class:`GaveUp`; an optional stop flag (a ``threading.Event`` for
:func:`retrying`, an ``asyncio.Event`` for :func:`async_retrying`) that cuts a wait short and
ends the retries with :class:`Stopped`. Each retry logs one line saying what it waits for, the
error, and when it tries again.

Both return a tenacity object, used as a call or a loop::

    url = retrying("the broker at amqp://u:****@host/", on=NoAnswer, deadline=60)(probe, url)

    async for attempt in async_retrying("the store", on=StoreUnavailable, stop=stopping):
        with attempt:
            await store.write(batch)
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar, cast

from tenacity import AsyncRetrying, RetryCallState, Retrying, retry_if_exception_type, stop_any, stop_never
from tenacity.stop import stop_after_delay, stop_base

from fleetbus.publishers.backoff import Backoff

log = logging.getLogger("fleetbus.retry")
T = TypeVar("T")

Transient = type[BaseException] | tuple[type[BaseException], ...]
OnRetry = Callable[[RetryCallState], None]

__all__ = ["Backoff", "GaveUp", "Stopped", "async_retrying", "pause", "retrying", "run_retrying"]
DEFAULT_BACKOFF = Backoff()


class GaveUp(Exception):
    """The deadline passed and the operation still failed; the message says what was waited for."""

    def __init__(self, what: str, waited: float, attempts: int, error: BaseException | None) -> None:
        self.what = what
        self.waited = waited
        self.attempts = attempts
        self.error = error
        super().__init__(f"{what} did not succeed in {waited:.1f} s ({attempts} attempts; last: {error})")


class Stopped(Exception):
    """The stop flag was set while the operation was failing; the last error is its cause."""


class _Flag(stop_base):
    """Stop once the flag is set (either kind of event: both have ``is_set``)."""

    def __init__(self, flag: threading.Event | asyncio.Event) -> None:
        self.flag = flag

    def __call__(self, retry_state: RetryCallState) -> bool:
        return self.flag.is_set()


class _Wait:
    """A tenacity wait drawn from the backoff policy, never past the deadline (so the last attempt
    is made right at it, not skipped)."""

    def __init__(self, backoff: Backoff, deadline: float | None) -> None:
        self._backoff = backoff
        self._deadline = deadline

    def __call__(self, retry_state: RetryCallState) -> float:
        delay = self._backoff.delay(retry_state.attempt_number - 1)
        if self._deadline is not None:
            delay = min(delay, max(0.0, self._deadline - (retry_state.seconds_since_start or 0.0)))
        return delay


def _options(
    what: str,
    on: Transient,
    deadline: float | None,
    backoff: Backoff,
    flag: threading.Event | asyncio.Event | None,
    logger: logging.Logger,
    on_retry: OnRetry | None,
) -> dict[str, object]:
    stops: list[stop_base] = []
    if deadline is not None:
        stops.append(stop_after_delay(deadline))
    if flag is not None:
        stops.append(_Flag(flag))

    def before_sleep(state: RetryCallState) -> None:
        if on_retry is not None:
            on_retry(state)
        error = state.outcome.exception() if state.outcome else None
        left = (
            ""
            if deadline is None
            else f", giving up in {max(0.0, deadline - state.seconds_since_start):.0f} s"
        )
        logger.warning(
            "waiting for %s: %s; retry %d in %.1f s%s",
            what,
            error,
            state.attempt_number,
            state.upcoming_sleep,
            left,
        )

    def give_up(state: RetryCallState) -> None:
        error = state.outcome.exception() if state.outcome else None
        if flag is not None and flag.is_set():
            raise Stopped(f"stopped while waiting for {what} ({error})") from error
        raise GaveUp(what, state.seconds_since_start or 0.0, state.attempt_number, error) from error

    return {
        "retry": retry_if_exception_type(on),
        "wait": _Wait(backoff, deadline),
        "stop": stop_any(*stops) if stops else stop_never,
        "before_sleep": before_sleep,
        "retry_error_callback": give_up,
    }


def retrying(
    what: str,
    *,
    on: Transient,
    deadline: float | None = None,
    backoff: Backoff = DEFAULT_BACKOFF,
    stop: threading.Event | None = None,
    logger: logging.Logger = log,
    on_retry: OnRetry | None = None,
) -> Retrying:
    """Retry while ``on`` is raised: until it succeeds, ``deadline`` seconds pass (:class:`GaveUp`)
    or ``stop`` is set (:class:`Stopped`, with a wait in progress cut short). Any other error
    is raised at once. ``what`` names what is waited for in the log and errors (mask passwords:
    :func:`fleetbus.broker.urls.mask_password`); ``on_retry`` is called before each wait (to count them)."""
    sleep = stop.wait if stop is not None else time.sleep
    return Retrying(sleep=sleep, **_options(what, on, deadline, backoff, stop, logger, on_retry))  # type: ignore[arg-type]


async def pause(seconds: float, stop: asyncio.Event) -> bool:
    """Wait ``seconds``, or less once ``stop`` is set; whether it is set."""
    with contextlib.suppress(asyncio.TimeoutError):
        await asyncio.wait_for(stop.wait(), seconds)
    return stop.is_set()


def async_retrying(
    what: str,
    *,
    on: Transient,
    deadline: float | None = None,
    backoff: Backoff = DEFAULT_BACKOFF,
    stop: asyncio.Event | None = None,
    logger: logging.Logger = log,
    on_retry: OnRetry | None = None,
) -> AsyncRetrying:
    """:func:`retrying` for coroutines, on the event loop (``stop`` is an ``asyncio.Event``)."""

    async def sleep(seconds: float) -> None:
        if stop is None:
            await asyncio.sleep(seconds)
        else:
            await pause(seconds, stop)

    return AsyncRetrying(sleep=sleep, **_options(what, on, deadline, backoff, stop, logger, on_retry))  # type: ignore[arg-type]


async def run_retrying(retrying: AsyncRetrying, operation: Callable[[], Awaitable[T]]) -> T:
    """Await ``operation()`` under ``retrying`` (an :func:`async_retrying`). tenacity awaits only
    coroutine functions; a lambda that returns a coroutine would come back unawaited."""

    async def attempt() -> T:
        return await operation()

    return cast(T, await retrying(attempt))
