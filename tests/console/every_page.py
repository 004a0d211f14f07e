"""Every page of the console and who may open it: a team staged so that the pages show their
buttons and tables, each role's user, and the paths each role's pages are at. The layout, axe and
HTML checks walk the same pages."""

from __future__ import annotations

from datetime import datetime, timezone

import pika

from fleetbus.api.console.sitemap import ACCOUNT, MESSAGES, MISSION_ROLES, pages_for
from fleetbus.api.services.alerts import AlertKind
from fleetbus.api.services.missions import AUTHORS
from fleetbus.schemas.missions import MissionState
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import DEAD_LETTER_EXCHANGE, RobotKind
from fleetbus.workers.store.alerts import NewAlert
from tests.console.support import Console
from tests.console.test_missions import PLAN

#: Every role with a page in the console, by the name of its user here.
ROLES = {role: f"as-{role.value}" for role in UserRole if role is not UserRole.ROBOT and pages_for(role)}


def stage_team(console: Console) -> None:
    """A mission in progress, owned by the client, with explorer1 mounted by the operator; explorer2
    free; a dead letter; an alert to acknowledge (every page's banner shows it)."""
    for role, name in ROLES.items():
        console.user(name, role)
    console.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
    console.user("explorer2", UserRole.ROBOT, RobotKind.EXPLORER)
    svc = console.service

    async def in_progress() -> None:
        users = svc.repositories.users
        client, supervisor, operator = [
            await users.get_user(ROLES[role])
            for role in (UserRole.CLIENT, UserRole.SUPERVISOR, UserRole.OPERATOR)
        ]
        assert client and supervisor and operator
        created = await svc.missions.create(client, "hazard-response", "Survey the north yard", PLAN)
        await svc.missions.transition(client, created.mission_id, MissionState.FILED)
        for state in (MissionState.APPROVED, MissionState.IN_PROGRESS):
            await svc.missions.transition(supervisor, created.mission_id, state)
        await svc.channels.mount(operator, "explorer1", created.mission_id)
        now = datetime.now(timezone.utc)
        low = NewAlert(AlertKind.BATTERY_LOW.value, "explorer2", now, "battery at 12 %", 12.0)
        await svc.repositories.alerts.raise_alerts([low], now)

    console.run(in_progress)
    with console.bus.admin_channel() as channel:
        channel.confirm_delivery()
        channel.basic_publish(DEAD_LETTER_EXCHANGE, "", b"refused", pika.BasicProperties(delivery_mode=2))


def page_paths(role: UserRole) -> list[str]:
    """The navigation's pages, and those reached from them: the own account (linked from the
    header), a mission, and the messages' trace and a robot's timeline."""
    paths = [page.path for page in pages_for(role)]
    if ACCOUNT.admits(role):
        paths.append(ACCOUNT.path)
    if MESSAGES.admits(role):
        paths += ["/console/messages/trace", "/console/messages/timeline?robot=explorer1"]
    if role in MISSION_ROLES:
        paths.append("/console/missions/m-1")
    if role in AUTHORS:
        paths.append("/console/missions/new")
    return paths
