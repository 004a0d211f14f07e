"""The application services for a process without an HTTP API of its own (the command line): the
services the routes and the console use, on the settings' store, opened for one operation."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING

from fleetbus.api.services.beacons import BeaconDiscards, Beacons
from fleetbus.api.services.hazard_steps import HazardSteps
from fleetbus.api.services.hazards import Hazards
from fleetbus.api.services.maps import Maps
from fleetbus.api.services.mission_comments import MissionComments
from fleetbus.api.services.missions import Missions
from fleetbus.api.services.team import Team, team_for
from fleetbus.settings import Settings
from fleetbus.workers.store import Repositories, open_recording_store, open_repositories
from fleetbus.workers.store.users import UserStore

# The services only some commands use are imported when asked for: every command that opens the
# services loads this module.
if TYPE_CHECKING:
    from fleetbus.api.services.alerts import Alerts, DeadLetterCount
    from fleetbus.api.services.dead_letters import DeadLetters
    from fleetbus.api.services.ledger import Ledger
    from fleetbus.api.services.recording import Recording
    from fleetbus.api.services.sessions import UserSessions
    from fleetbus.api.services.shards import Shards
    from fleetbus.api.services.sites import Sites, SiteTeam
    from fleetbus.api.services.stats import Stats


class Services:
    """Each service built when first asked for, on one set of repositories."""

    def __init__(self, settings: Settings, repositories: Repositories, admin_url: str | None) -> None:
        self._settings = settings
        self._repos = repositories
        self._admin_url = admin_url

    def _broker(self) -> str:
        if self._admin_url is None:
            raise RuntimeError("the services were opened without a broker: open them with its admin_url")
        return self._admin_url

    @property
    def team(self) -> Team:
        return team_for(self._settings, self._repos.hazards, self._repos.events, self._admin_url)

    @property
    def hazards(self) -> Hazards:
        return Hazards(self._repos.hazards, self._repos.events)

    @property
    def hazard_steps(self) -> HazardSteps:
        return HazardSteps(self._repos.hazards, self._repos.channels, self._broker())

    @property
    def beacons(self) -> Beacons:
        return Beacons(self._repos.beacons, self._repos.events, self._settings.beacon_window_max)

    @property
    def beacon_discards(self) -> BeaconDiscards:
        return BeaconDiscards(self._repos.discards)

    @property
    def maps(self) -> Maps:
        return Maps(self._repos.maps)

    def alerts(self, dead_letters: DeadLetterCount | None = None) -> Alerts:
        """The alerts, with the settings' thresholds; ``dead_letters`` counts the dead-letter queue
        (None: its alerts are left as they are)."""
        from fleetbus.api.services.alerts import alerts_for

        return alerts_for(self._settings, self._repos, dead_letters)

    @property
    def dead_letters(self) -> DeadLetters:
        from fleetbus.api.services.dead_letters import DeadLetters

        return DeadLetters(self._repos.rejections, self._repos.housekeeping, self._broker())

    @property
    def ledger(self) -> Ledger:
        from fleetbus.api.services.ledger import Ledger

        return Ledger(self._repos.events)

    @property
    def sessions(self) -> UserSessions:
        from fleetbus.api.services.sessions import UserSessions

        return UserSessions(self._repos.users, self._repos.sessions)

    @property
    def shards(self) -> Shards:
        from fleetbus.api.services.shards import Shards

        return Shards(self._repos.leases, self._repos.users)

    @property
    def sites(self) -> Sites:
        """Central's sites; needs the broker (their reports wait there, missions go there)."""
        from fleetbus.api.services.sites import Sites

        return Sites(self._repos.sites, self._repos.missions, self._broker(), self._settings.uplink_alert_at)

    @property
    def site_team(self) -> SiteTeam:
        from fleetbus.api.services.sites import SiteTeam

        return SiteTeam(self._repos.hazards, self._repos.channels)

    @property
    def stats(self) -> Stats:
        from fleetbus.api.services.stats import Stats

        return Stats(self._repos.statuses, self._repos.housekeeping)

    @property
    def missions(self) -> Missions:
        """The missions; opened with a broker, each change is sent to the sites (else `fleetbus
        sites sync` sends them)."""
        if self._admin_url is None:
            return Missions(self._repos.missions, self._repos.channels)
        from fleetbus.workers.sites import send_mission_to_sites

        sites, admin_url = self._repos.sites, self._admin_url
        return Missions(
            self._repos.missions,
            self._repos.channels,
            lambda mission: send_mission_to_sites(sites, admin_url, mission),
        )

    @property
    def mission_comments(self) -> MissionComments:
        return MissionComments(Missions(self._repos.missions, self._repos.channels), self._repos.comments)

    @property
    def users(self) -> UserStore:
        """The account registry, for a command that acts as one of its accounts."""
        return self._repos.users


@asynccontextmanager
async def open_services(settings: Settings, admin_url: str | None = None) -> AsyncIterator[Services]:
    """The services on the settings' store; ``admin_url``: the administrator's broker, which the
    changes that tell the robots or the hazard service need (none to only read)."""
    async with open_repositories(settings) as repositories:
        yield Services(settings, repositories, admin_url)


@asynccontextmanager
async def open_recording(settings: Settings, events: bool = False) -> AsyncIterator[Recording]:
    """The recording the settings select; ``events``: with the event log, which a trace reads."""
    from fleetbus.api.services.recording import Recording

    async with open_recording_store(settings) as store:
        if not events:
            yield Recording(store)
            return
        async with open_repositories(settings) as repositories:
            yield Recording(store, repositories.events)
