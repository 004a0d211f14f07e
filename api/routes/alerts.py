"""Alerts the operators acknowledge: the list, and acknowledging one (who and when is recorded)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import AlertOut, AlertsOut
from fleetbus.api.openapi import refusals
from fleetbus.api.parameters import AlertId
from fleetbus.api.services.accounts import User
from fleetbus.api.services.alerts import ACKNOWLEDGERS
from fleetbus.api.services.errors import Conflict
from fleetbus.schemas.roles import WATCHERS

router = APIRouter(tags=["alerts"])
Watcher = Annotated[User, Depends(require_role(*WATCHERS))]
Acknowledger = Annotated[User, Depends(require_role(*ACKNOWLEDGERS))]


@router.get("/alerts", response_model=AlertsOut)
async def alerts(
    user: Watcher,
    svc: ServiceDep,
    acknowledged: Annotated[
        bool, Query(description="also list the last acknowledged alerts, with who acknowledged each and when")
    ] = False,
) -> AlertsOut:
    """The alerts to acknowledge (a hazard announced or unclaimed, a battery low, a robot stale, a
    site's uplink near its bound, dead letters growing), oldest first, each with its kind, subject,
    since when its condition holds and whether it has ended; the store is looked at first, as the
    background check does."""
    await svc.alerts.check()
    found = await svc.alerts.listing(acknowledged)
    return AlertsOut(
        unacknowledged=[AlertOut.of(alert) for alert in found.unacknowledged],
        acknowledged=[AlertOut.of(alert) for alert in found.acknowledged],
    )


@router.post("/alerts/{alert_id}/acknowledge", response_model=AlertOut, responses=refusals(Conflict))
async def acknowledge(alert_id: AlertId, user: Acknowledger, svc: ServiceDep) -> AlertOut:
    """Acknowledge an alert: the caller and the time (UTC) are recorded. An alert is acknowledged
    once: a second acknowledgement is refused (409), naming who acknowledged it and when."""
    return AlertOut.of(await svc.alerts.acknowledge(alert_id, user.name, user.role))
