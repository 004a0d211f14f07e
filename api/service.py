"""Everything the HTTP API works with, opened once for the app's life."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from api.accounts import Accounts
from api.channels import Channels
from api.missions import Missions
from api.security import Secrets
from broker.accounts import vhost_of
from broker.management import ManagementAPI
from fleetbus.config import Settings
from workers.store import open_store
from workers.store.interface import Store


@dataclass
class Service:
    settings: Settings
    store: Store
    secrets: Secrets
    accounts: Accounts
    missions: Missions
    channels: Channels


@asynccontextmanager
async def open_service(settings: Settings, admin_url: str, management_url: str) -> AsyncIterator[Service]:
    """The store, the broker's management API (as administrator) and the services on top."""
    secrets_ = Secrets.for_settings(settings)
    store = open_store(settings)
    await store.open()
    management = ManagementAPI.from_urls(management_url, admin_url)
    try:
        missions = Missions(store)
        yield Service(
            settings=settings,
            store=store,
            secrets=secrets_,
            accounts=Accounts(store, secrets_, management, admin_url),
            missions=missions,
            channels=Channels(store, management, vhost_of(admin_url), missions),
        )
    finally:
        management.close()
        await store.close()
