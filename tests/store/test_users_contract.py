"""Users on every adapter: unique names, exact round trips, partial updates."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pytest

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.users import NoSuchUser, User, UserExists

T0 = datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc)


def user(name: str = "alice", role: UserRole = UserRole.INACTIVE, **changes: object) -> User:
    base = User(
        name=name,
        role=role,
        password_hash="$argon2id$v=19$m=65536,t=3,p=4$c2FsdA$aGFzaA",
        broker_secret="gAAAA-encrypted",
        kind=None,
        created_at=T0,
        created_by="root",
        updated_at=T0,
    )
    return replace(base, **changes)  # type: ignore[arg-type]


async def test_a_user_round_trips_and_names_are_unique(store: Repositories) -> None:
    original = user(kind="warden", role=UserRole.ROBOT)
    await store.users.add_user(original)
    assert await store.users.get_user("alice") == original
    with pytest.raises(UserExists, match="alice"):
        await store.users.add_user(user(role=UserRole.ADMIN))
    assert (await store.users.get_user("alice")) == original, "a refused add changes nothing"
    assert await store.users.get_user("bob") is None


async def test_users_list_by_name_and_role(store: Repositories) -> None:
    for name, role in (("carol", UserRole.OPERATOR), ("alice", UserRole.ADMIN), ("bob", UserRole.OPERATOR)):
        await store.users.add_user(user(name, role))
    assert [u.name for u in await store.users.users()] == ["alice", "bob", "carol"]
    assert [u.name for u in await store.users.users(UserRole.OPERATOR)] == ["bob", "carol"]
    assert await store.users.users(UserRole.GUEST) == []


async def test_update_changes_only_the_given_fields(store: Repositories) -> None:
    await store.users.add_user(user())
    later = T0 + timedelta(minutes=5)
    changed = await store.users.update_user("alice", later, role=UserRole.PLANNER)
    assert changed == user(role=UserRole.PLANNER, updated_at=later)
    rekeyed = await store.users.update_user(
        "alice", later, password_hash="new-hash", broker_secret="new-secret"
    )
    assert (rekeyed.role, rekeyed.password_hash, rekeyed.broker_secret) == (
        UserRole.PLANNER,
        "new-hash",
        "new-secret",
    )
    with pytest.raises(NoSuchUser, match="nobody"):
        await store.users.update_user("nobody", later, role=UserRole.ADMIN)


async def test_remove_user(store: Repositories) -> None:
    await store.users.add_user(user())
    assert await store.users.remove_user("alice") is True
    assert await store.users.remove_user("alice") is False
    assert await store.users.get_user("alice") is None


async def test_allowed_use_cases_round_trip_and_every_one_is_the_default(store: Repositories) -> None:
    await store.users.add_user(user())
    assert (await store.users.get_user("alice")).use_cases is None, "every use case until restricted"
    later = T0 + timedelta(minutes=5)
    restricted = await store.users.set_use_cases("alice", ("survey",), later)
    assert restricted == user(use_cases=("survey",), updated_at=later)
    assert await store.users.get_user("alice") == restricted
    kept = await store.users.update_user("alice", later, role=UserRole.CLIENT)
    assert kept.use_cases == ("survey",), "other changes keep them"
    assert (await store.users.set_use_cases("alice", (), later)).use_cases == (), "none at all"
    assert (await store.users.set_use_cases("alice", None, later)).use_cases is None
    await store.users.put_user(user(use_cases=("hazard-response", "survey")))
    assert (await store.users.get_user("alice")).use_cases == ("hazard-response", "survey")
    with pytest.raises(NoSuchUser, match="nobody"):
        await store.users.set_use_cases("nobody", ("survey",), later)
