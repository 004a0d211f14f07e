"""Which pages the console has and who may open each: the one list the navigation and the
access checks read."""

from __future__ import annotations

from dataclasses import dataclass

from fleetbus.schemas.roles import ACTIVE_ROLES, EVALUATORS, WATCHERS
from fleetbus.schemas.roles import UserRole as R


@dataclass(frozen=True)
class Page:
    name: str
    title: str
    path: str
    roles: frozenset[R]

    def admits(self, role: R) -> bool:
        return role in self.roles


#: Who manages accounts and changes the dead-letter queue.
ADMINS = frozenset({R.ADMIN})
#: Every role that may read missions.
MISSION_ROLES = frozenset({R.ADMIN, R.CLIENT, R.PLANNER, R.SUPERVISOR, R.OPERATOR, R.GUEST})

#: Every role that logs in to the console (a robot only fetches its broker credentials).
CONSOLE_ROLES = ACTIVE_ROLES - {R.ROBOT}

#: Everyone's work is on it; the team, hazards, broker and events are the watchers' only.
DASHBOARD = Page("dashboard", "Dashboard", "/console/", CONSOLE_ROLES)
MAP = Page("map", "Live map", "/console/map", WATCHERS)
HAZARDS = Page("hazards", "Hazards", "/console/hazards", WATCHERS)
MISSIONS = Page("missions", "Missions", "/console/missions", MISSION_ROLES)
MESSAGES = Page("messages", "Messages", "/console/messages", WATCHERS)
ALERTS = Page("alerts", "Alerts", "/console/alerts", WATCHERS)
DEAD_LETTERS = Page("dead-letters", "Dead letters", "/console/dead-letters", WATCHERS)
EVALUATION = Page("evaluation", "Evaluation", "/console/evaluation", EVALUATORS)
ACCOUNTS = Page("accounts", "Accounts", "/console/accounts", ADMINS | {R.SUPERVISOR})

#: Everyone's own account (not in the navigation: the user's name in the header links to it).
ACCOUNT = Page("account", "My account", "/console/account", CONSOLE_ROLES)

#: Every page, in the navigation's order.
PAGES: tuple[Page, ...] = (
    DASHBOARD,
    ALERTS,
    MAP,
    HAZARDS,
    MISSIONS,
    MESSAGES,
    DEAD_LETTERS,
    EVALUATION,
    ACCOUNTS,
)


def pages_for(role: R) -> list[Page]:
    """The pages ``role`` may open, in the navigation's order."""
    return [page for page in PAGES if page.admits(role)]


def home_for(role: R) -> Page | None:
    """Where a user lands after logging in: the first page it may open."""
    allowed = pages_for(role)
    return allowed[0] if allowed else None
