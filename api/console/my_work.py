"""What the dashboard shows every user of their own work, whatever the role: the missions not yet
closed that are theirs (:meth:`fleetbus.api.services.missions.Missions.active_for`), the robots they mounted,
and their broker login (its URL; the password only on request, once: :mod:`.shown_once`).

The panel is live: a dashboard's stream sends it again whenever it changed
(:class:`MyWorkPanels`, rendered at most twice a second for each user however many of their
pages are open); the broker login is not in it (a rotated password is shown once, on its own
page)."""

from __future__ import annotations

from functools import partial
from typing import Any

from fastapi import Request

from fleetbus.api.console.live import Shared
from fleetbus.api.console.templating import fragment
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


class MyWorkPanels:
    """Each user's My work panel as a live fragment. One render is shared by that user's open
    pages (a user's, not everyone's: it holds their missions and mounts); one entry a user who
    opened a live page, so the users' registry bounds them."""

    def __init__(self, service: Service) -> None:
        self._service = service
        self._renders: dict[str, tuple[str, Shared]] = {}
        """By user name: the role rendered for, and its shared render."""
        self._users: dict[str, User] = {}
        """The user as the latest page asking knew it (its use cases, its broker login)."""

    async def of(self, user: User) -> list[str]:
        self._users[user.name] = user
        role, render = self._renders.get(user.name, (None, None))
        if render is None or role != user.role.value:  # a new role is a new panel (its actions differ)
            render = Shared(partial(self._render, user.name))
            self._renders[user.name] = (user.role.value, render)
        return await render()

    async def _render(self, name: str) -> list[str]:
        user = self._users[name]
        mine = await my_work(self._service, user)
        return [fragment("dashboard/my_work.html", user=user, **mine)]


def my_work_panels(request: Request) -> MyWorkPanels:
    state = request.app.state
    if getattr(state, "my_work_panels", None) is None:
        state.my_work_panels = MyWorkPanels(state.service)
    return state.my_work_panels


async def my_work_panel(request: Request) -> list[str]:
    """The signed-in user's panel, for a live page's stream (none for a stream without one)."""
    user: User | None = getattr(request.state, "user", None)
    return await my_work_panels(request).of(user) if user is not None else []
