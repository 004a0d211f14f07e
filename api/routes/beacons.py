"""What the beacon exchange discarded, counted by publishing exchange."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.models import DiscardCountOut, DiscardOut, DiscardsOut
from fleetbus.api.services.accounts import User
from fleetbus.schemas.roles import UserRole

router = APIRouter(tags=["beacons"])
Watcher = Annotated[User, Depends(require_role(UserRole.OPERATOR, UserRole.SUPERVISOR, UserRole.ADMIN))]


@router.get("/beacons/discards", response_model=DiscardsOut)
async def discards(
    user: Watcher, svc: ServiceDep, recent: Annotated[int, Query(ge=0, le=1000)] = 20
) -> DiscardsOut:
    """Beacon messages without the ``type: beacon`` and ``codename`` headers, which the broker discarded."""
    return DiscardsOut(
        counts=[DiscardCountOut.of(c) for c in await svc.beacon_discards.counts()],
        recent=[DiscardOut.of(d) for d in await svc.beacon_discards.recent(recent)] if recent else [],
    )
