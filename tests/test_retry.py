"""The one retry policy (broker/retry.py): backoff, deadline, stop flag and its log line, sync and async."""

from __future__ import annotations

import asyncio
import logging
import re
import threading
import time

import pytest

from fleetbus.broker.retry import Backoff, GaveUp, Stopped, async_retrying, retrying

FAST = Backoff(initial=0.01, maximum=0.05, jitter=0.01)


class Flaky:
    """Fails with ``error`` ``failures`` times, then returns the number of calls."""

    def __init__(self, failures: int, error: type[Exception] = ConnectionError) -> None:
        self.failures = failures
        self.error = error
        self.calls = 0

    def __call__(self) -> int:
        self.calls += 1
        if self.calls <= self.failures:
            raise self.error(f"failure {self.calls}")
        return self.calls

    async def coroutine(self) -> int:
        return self()


def test_a_transient_failure_is_retried_and_each_retry_says_what_it_waits_for(
    caplog: pytest.LogCaptureFixture,
) -> None:
    flaky = Flaky(3)
    counted: list[int] = []
    with caplog.at_level(logging.WARNING, "fleetbus.retry"):
        result = retrying(
            "the thing at amqp://u:****@host/",
            on=ConnectionError,
            backoff=FAST,
            on_retry=lambda state: counted.append(state.attempt_number),
        )(flaky)
    assert result == 4 and counted == [1, 2, 3]
    lines = [record.getMessage() for record in caplog.records]
    assert len(lines) == 3
    assert lines[0].startswith("waiting for the thing at amqp://u:****@host/: failure 1; retry 1 in 0.0")


def test_another_error_is_raised_at_once() -> None:
    flaky = Flaky(1, ValueError)
    with pytest.raises(ValueError, match="failure 1"):
        retrying("x", on=ConnectionError, backoff=FAST)(flaky)
    assert flaky.calls == 1


def test_the_deadline_ends_the_retries_with_what_was_waited_for_and_the_last_error() -> None:
    flaky = Flaky(10_000)
    started = time.monotonic()
    with pytest.raises(GaveUp) as raised:
        retrying("the broker", on=ConnectionError, deadline=0.5, backoff=Backoff(0.05, 0.2, 0.0))(flaky)
    took = time.monotonic() - started
    assert 0.5 <= took < 3.0, "the last attempt is made at the deadline, not skipped nor long after"
    assert raised.value.attempts == flaky.calls > 2
    assert isinstance(raised.value.error, ConnectionError)
    assert re.match(r"the broker did not succeed in \d+\.\d s ", str(raised.value))
    assert str(raised.value).endswith(f"({flaky.calls} attempts; last: failure {flaky.calls})")


def test_waits_grow_exponentially_up_to_the_cap() -> None:
    waits: list[float] = []
    flaky = Flaky(6)
    retrying(
        "x",
        on=ConnectionError,
        backoff=Backoff(initial=0.01, maximum=0.04, jitter=0.0),
        on_retry=lambda state: waits.append(state.upcoming_sleep),
    )(flaky)
    assert waits == pytest.approx([0.01, 0.02, 0.04, 0.04, 0.04, 0.04])


def test_the_stop_flag_cuts_a_wait_short() -> None:
    stop = threading.Event()
    flaky = Flaky(10_000)
    threading.Timer(0.2, stop.set).start()
    started = time.monotonic()
    with pytest.raises(Stopped, match="stopped while waiting for the store"):
        retrying("the store", on=ConnectionError, backoff=Backoff(30.0, 30.0, 0.0), stop=stop)(flaky)
    assert time.monotonic() - started < 5, "a 30 s wait was not cut short"


async def test_the_async_form_retries_and_stops_on_an_asyncio_event() -> None:
    flaky = Flaky(2)
    assert await async_retrying("the store", on=ConnectionError, backoff=FAST)(flaky.coroutine) == 3

    stop = asyncio.Event()
    asyncio.get_running_loop().call_later(0.2, stop.set)
    endless = Flaky(10_000)
    started = time.monotonic()
    with pytest.raises(Stopped) as raised:
        async for attempt in async_retrying(
            "the store", on=ConnectionError, backoff=Backoff(30.0, 30.0, 0.0), stop=stop
        ):
            with attempt:
                endless()
    assert time.monotonic() - started < 5
    assert isinstance(raised.value.__cause__, ConnectionError)


async def test_the_async_form_gives_up_at_its_deadline() -> None:
    flaky = Flaky(10_000)
    with pytest.raises(GaveUp):
        await async_retrying("x", on=ConnectionError, deadline=0.3, backoff=FAST)(flaky.coroutine)
    assert flaky.calls > 2
