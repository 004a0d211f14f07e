"""Everything the HTTP API works with, opened once for the app's life."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from fleetbus.api.services.account_check import AccountCheck, account_check_for
from fleetbus.api.services.accounts import Accounts, accounts_for
from fleetbus.api.services.alerts import Alerts, alerts_for
from fleetbus.api.services.beacons import BeaconDiscards, Beacons
from fleetbus.api.services.channels import Channels
from fleetbus.api.services.dead_letters import DeadLetters
from fleetbus.api.services.hazard_steps import HazardSteps
from fleetbus.api.services.hazards import Hazards
from fleetbus.api.services.ledger import Ledger
from fleetbus.api.services.login_limits import LoginLimits
from fleetbus.api.services.maps import Maps
from fleetbus.api.services.mission_comments import MissionComments
from fleetbus.api.services.missions import Missions
from fleetbus.api.services.missions_to_sites import MissionsToSites
from fleetbus.api.services.recording import Recording
from fleetbus.api.services.security import Secrets
from fleetbus.api.services.sessions import Sessions, SignedIn
from fleetbus.api.services.sites import Sites
from fleetbus.api.services.stored_events import MissionEvents, StoredEvents
from fleetbus.api.services.team import Team, team_for
from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.dead_letter_queue import DeadLetter, dead_letters_waiting
from fleetbus.broker.management import ManagementAPI, connections_by_user
from fleetbus.broker.routes import RouteMap
from fleetbus.settings import Settings
from fleetbus.workers.sites import send_mission_to_sites
from fleetbus.workers.store import Repositories, open_recording_store, repositories_for
from fleetbus.workers.store.recordings import RecordingStore


@dataclass
class Service:
    settings: Settings
    repositories: Repositories
    """The repositories the services below are built on; the routes and the console call the
    services."""
    secrets: Secrets
    sessions: Sessions
    """Login sessions: begun at login, checked on every request, ended server-side."""
    accounts: Accounts
    account_check: AccountCheck
    """The registry against the broker, the team and the sites: drift, and its repair."""
    missions: Missions
    channels: Channels
    team: Team
    hazard_steps: HazardSteps
    """Steps of a hazard an operator takes for a warden (claim, reached, cleared, release)."""
    recording: RecordingStore
    management: ManagementAPI
    admin_url: str
    """The administrator's AMQP URL (the console reads and changes the dead-letter queue with it)."""
    vhost: str
    login_limits: LoginLimits
    alerts: Alerts
    """The alerts raised for the operators from the store (checked in the background) and their
    acknowledgements."""
    events: StoredEvents
    """The event log's reads behind the console's live parts (its feed, each robot's newest)."""
    mission_events: MissionEvents
    """A mission's recorded events, for whoever may see the mission."""
    hazards: Hazards
    """The hazards of every mission as the lists, the dashboard and the map show them."""
    sites: Sites
    """Central's sites: what each forwarded and its newest report (none elsewhere)."""
    ledger: Ledger
    """The open gaps in the robots' sequence numbers, and the duplicates the workers recognised."""
    maps: Maps
    """The stored versions of the team's map (:meth:`Maps.visible`: those a user may see)."""
    beacons: Beacons
    """The beacon registry and where people are likely stranded."""
    recording_queries: Recording
    """The recording's search, timelines, traces, evaluation and growth."""
    beacon_discards: BeaconDiscards
    """The beacon messages the broker discarded, counted by publishing exchange."""
    signed_in: SignedIn
    """Who a request's token signs in (the API's bearer token, the console's cookie)."""
    mission_comments: MissionComments
    """The missions' discussions: who reads and who adds to them."""

    async def dead_letters(self, limit: int) -> list[DeadLetter]:
        """Up to ``limit`` dead letters, oldest first, each with the reason the store kept, as
        ``fleetbus dlq`` lists them (nothing is removed from the queue)."""
        return (await self.dead_letter_queue.listing(limit)).letters

    @property
    def dead_letter_queue(self) -> DeadLetters:
        """The dead-letter queue's service (its letters and what the full queue dropped), as the
        command line has it."""
        return DeadLetters(self.repositories.rejections, self.repositories.housekeeping, self.admin_url)

    async def route_map(self) -> RouteMap:
        """The broker's exchanges, bindings and consumers now (the management API, off the loop)."""
        return await asyncio.to_thread(RouteMap.from_management, self.management, self.vhost)


@asynccontextmanager
async def open_service(
    settings: Settings, admin_url: str, management_url: str, public_url: str | None = None
) -> AsyncIterator[Service]:
    """The repositories, the broker's management API (as administrator) and the services on top;
    ``public_url`` (else ``FLEETBUS_PUBLIC_AMQP_URL``) is the broker address users are handed."""
    secrets_ = Secrets.for_settings(settings)
    repositories = repositories_for(settings)
    await repositories.open()
    recording = open_recording_store(settings)
    await recording.open()
    management = ManagementAPI.from_urls(management_url, admin_url)
    to_sites = MissionsToSites(lambda mission: send_mission_to_sites(repositories.sites, admin_url, mission))
    to_sites.start()
    sessions = Sessions(repositories.sessions, secrets_.tokens, settings.api_sessions_per_user)
    vhost = vhost_of(admin_url)
    sites = Sites(repositories.sites, repositories.missions, admin_url, settings.uplink_alert_at)
    alerts = alerts_for(
        settings,
        repositories,
        lambda: asyncio.to_thread(dead_letters_waiting, management, vhost),
        lambda: asyncio.to_thread(connections_by_user, management, vhost),
        # the reports wait in the broker until read: with no dashboard open, the alerts read them
        sites.collect,
    )
    checking = asyncio.create_task(
        alerts.keep_checking(settings.alerts_check_s, settings.alerts_hazard_check_s), name="alerts-check"
    )
    try:
        missions = Missions(repositories.missions, repositories.channels, to_sites.changed)
        accounts = accounts_for(
            settings, repositories, secrets_, management, admin_url, public_url, sessions=sessions
        )
        yield Service(
            settings=settings,
            repositories=repositories,
            secrets=secrets_,
            sessions=sessions,
            accounts=accounts,
            account_check=account_check_for(
                accounts, repositories, management, admin_url, settings.ingest_shards
            ),
            missions=missions,
            channels=Channels(
                repositories.channels, repositories.users, management, vhost_of(admin_url), missions
            ),
            team=team_for(settings, repositories.hazards, repositories.events, admin_url),
            hazard_steps=HazardSteps(repositories.hazards, repositories.channels, admin_url),
            recording=recording,
            management=management,
            admin_url=admin_url,
            vhost=vhost_of(admin_url),
            login_limits=LoginLimits(settings.api_account_failures, settings.api_address_failures),
            alerts=alerts,
            events=StoredEvents(repositories.events),
            mission_events=MissionEvents(missions, repositories.events),
            hazards=Hazards(repositories.hazards, repositories.events),
            sites=sites,
            ledger=Ledger(repositories.events),
            maps=Maps(repositories.maps),
            beacons=Beacons(repositories.beacons, repositories.events, settings.beacon_window_max),
            recording_queries=Recording(recording, repositories.events),
            beacon_discards=BeaconDiscards(repositories.discards),
            signed_in=SignedIn(sessions, repositories.users),
            mission_comments=MissionComments(missions, repositories.comments),
        )
    finally:
        checking.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await checking
        await to_sites.stop()
        secrets_.passwords.close()
        management.close()
        await recording.close()
        await repositories.close()
