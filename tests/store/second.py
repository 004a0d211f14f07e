"""A second, independent connection to the same database as a test's store: a concurrent writer."""

from __future__ import annotations

from fleetbus.workers.store.repositories import Repositories


def second_connection(store: Repositories) -> Repositories:
    """Not yet opened; use ``async with``."""
    return store.again()
