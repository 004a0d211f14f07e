"""What the dashboard shows every user of their own work, whatever the role: the missions not yet
closed that are theirs (:meth:`fleetbus.api.services.missions.Missions.active_for`), the robots they mounted,
and their broker login (its URL; the password only on request, once: :mod:`.shown_once`)."""

from __future__ import annotations

from typing import Any

from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.missions import AUTHORS

#: Missions listed; the rest are counted.
MISSIONS_SHOWN = 20


async def my_work(svc: Service, user: User) -> dict[str, Any]:
    """The template context of ``dashboard/my_work.html``."""
    missions = await svc.missions.active_for(user)
    return {
        "my_missions": missions[:MISSIONS_SHOWN],
        "my_missions_more": max(0, len(missions) - MISSIONS_SHOWN),
        "my_mounts": await svc.channels.mounts(operator=user.name),
        "may_create": user.role in AUTHORS,
        "broker": broker_login(svc, user),
    }


def broker_login(svc: Service, user: User) -> dict[str, Any]:
    """The user's broker login as a page may show it: no password."""
    return {
        "username": user.name,
        "url": svc.accounts.broker_address(user),
        "has_password": user.broker_secret is not None,
    }
