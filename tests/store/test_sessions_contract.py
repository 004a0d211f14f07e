"""Login sessions on every adapter: exact round trips, the per-user bound, ending and expiry."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sessions import Session

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)
HOUR = timedelta(hours=1)


def session(sid: str, user: str = "alice", begun: datetime = T0, lasts: timedelta = HOUR) -> Session:
    return Session(sid, user, begun, begun, begun + lasts, "192.0.2.7", "curl/8.0")


async def test_a_session_round_trips_and_lists_newest_first(store: Repositories) -> None:
    first = session("s1")
    assert await store.sessions.begin_session(first, most=5) == []
    assert await store.sessions.get_session("s1") == first
    second = Session("s2", "alice", T0 + timedelta(seconds=1), T0, T0 + HOUR, None, None)
    await store.sessions.begin_session(second, most=5)
    await store.sessions.begin_session(session("s3", "bob"), most=5)
    assert await store.sessions.sessions_of("alice", T0) == [second, first]
    assert await store.sessions.get_session("nope") is None


async def test_beginning_one_more_than_the_bound_ends_the_oldest_and_the_expired(
    store: Repositories,
) -> None:
    await store.sessions.begin_session(session("old", lasts=timedelta(seconds=1)), most=2)
    for n in range(1, 3):
        await store.sessions.begin_session(session(f"s{n}", begun=T0 + timedelta(seconds=n)), most=2)
    assert [s.id for s in await store.sessions.sessions_of("alice", T0)] == ["s2", "s1"]
    ended = await store.sessions.begin_session(session("s3", begun=T0 + timedelta(seconds=3)), most=2)
    assert set(ended) == {"s1"}
    assert await store.sessions.get_session("old") is None, "expired at s2's start: ended then"
    assert [s.id for s in await store.sessions.sessions_of("alice", T0)] == ["s3", "s2"]


async def test_ending_one_all_or_all_but_one(store: Repositories) -> None:
    for sid in ("a1", "a2", "a3"):
        await store.sessions.begin_session(session(sid), most=10)
    await store.sessions.begin_session(session("b1", "bob"), most=10)
    assert not await store.sessions.end_session("a1", "bob"), "only the owner's session ends"
    assert await store.sessions.end_session("a1", "alice")
    assert not await store.sessions.end_session("a1", "alice")
    assert await store.sessions.end_sessions("alice", keep="a2") == 1
    assert [s.id for s in await store.sessions.sessions_of("alice", T0)] == ["a2"]
    assert await store.sessions.end_sessions("alice") == 1
    assert await store.sessions.sessions_of("alice", T0) == []
    assert await store.sessions.get_session("b1") is not None


async def test_a_sighting_is_written_at_most_once_per_interval_and_expired_ones_are_pruned(
    store: Repositories,
) -> None:
    await store.sessions.begin_session(session("s1"), most=10)
    minute = timedelta(minutes=1)
    await store.sessions.session_seen("s1", T0 + timedelta(seconds=30), minute)
    assert (await store.sessions.get_session("s1")).last_seen == T0  # type: ignore[union-attr]
    await store.sessions.session_seen("s1", T0 + timedelta(seconds=90), minute)
    assert (await store.sessions.get_session("s1")).last_seen == T0 + timedelta(seconds=90)  # type: ignore[union-attr]
    assert await store.sessions.sessions_of("alice", T0 + HOUR) == [], "expired: not listed"
    assert await store.sessions.prune_sessions(T0 + HOUR) == 1
    assert await store.sessions.get_session("s1") is None
