"""Attempt counts on every adapter: counted durably per key, forgotten once handled."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.repositories import Repositories
from tests.store.second import second_connection

T0 = datetime(2026, 11, 24, 8, 0, 0, tzinfo=timezone.utc)


async def test_attempts_are_counted_per_key_and_survive_a_new_connection(store: Repositories) -> None:
    assert [await store.attempts.count_attempt("robot1:m1", T0 + timedelta(seconds=i)) for i in range(3)] == [
        1,
        2,
        3,
    ]
    assert await store.attempts.count_attempt("robot1:m2", T0) == 1, "another message counts on its own"
    other = second_connection(store)  # what a restarted worker sees
    await other.open()
    try:
        assert await other.attempts.count_attempt("robot1:m1", T0) == 4
    finally:
        await other.close()


async def test_forgotten_attempts_count_from_one_again(store: Repositories) -> None:
    for _ in range(2):
        await store.attempts.count_attempt("robot1:m1", T0)
    await store.attempts.count_attempt("robot1:m2", T0)
    await store.attempts.forget_attempts(["robot1:m1", "robot1:never-counted"])
    await store.attempts.forget_attempts([])
    assert await store.attempts.count_attempt("robot1:m1", T0) == 1
    assert await store.attempts.count_attempt("robot1:m2", T0) == 2, "only the keys named are forgotten"
