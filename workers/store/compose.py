"""The composition root: every repository over one database (:func:`repositories_on`)."""

from __future__ import annotations

from fleetbus.workers.store.alerts import Alerts
from fleetbus.workers.store.attempts import Attempts
from fleetbus.workers.store.beacons import Beacons
from fleetbus.workers.store.channels import Channels
from fleetbus.workers.store.comments import Comments
from fleetbus.workers.store.discards import Discards
from fleetbus.workers.store.event_log import Events
from fleetbus.workers.store.hazards import Coordination
from fleetbus.workers.store.housekeeping import StoreHousekeeping
from fleetbus.workers.store.leases import Leases
from fleetbus.workers.store.maps import Maps
from fleetbus.workers.store.missions import Missions
from fleetbus.workers.store.port import Database
from fleetbus.workers.store.rejections import Rejections
from fleetbus.workers.store.repositories import Repositories
from fleetbus.workers.store.sessions import Sessions
from fleetbus.workers.store.sites import Sites
from fleetbus.workers.store.statuses import Statuses
from fleetbus.workers.store.users import Users


def repositories_on(database: Database) -> Repositories:
    """Every repository over ``database``, not yet opened (opening it makes their collections)."""
    channels = Channels(database)
    return Repositories(
        name=database.name,
        events=Events(database, channels),
        hazards=Coordination(database),
        beacons=Beacons(database),
        maps=Maps(database),
        missions=Missions(database),
        channels=channels,
        users=Users(database),
        sessions=Sessions(database),
        discards=Discards(database),
        rejections=Rejections(database),
        attempts=Attempts(database),
        leases=Leases(database),
        statuses=Statuses(database),
        housekeeping=StoreHousekeeping(database),
        sites=Sites(database),
        alerts=Alerts(database),
        comments=Comments(database),
        opener=database.open,
        closer=database.close,
        again=lambda: repositories_on(database.again()),
        any_loop=database.any_loop,
    )
