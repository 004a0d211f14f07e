"""A mission's discussion: who may read it, who may add to it, and what a comment may be.

One rule for the HTTP API, the command line and the console: whoever may see the mission reads
its thread (:meth:`~fleetbus.api.services.missions.Missions.get`: a client its own missions); the client
who owns the mission, planners, supervisors, operators and administrators comment on it. Guests
read only; robots neither.
"""

from __future__ import annotations

from datetime import datetime, timezone

from fleetbus.api.services.errors import BadRequest, Forbidden
from fleetbus.api.services.missions import Missions
from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.comments import Comment, CommentStore
from fleetbus.workers.store.missions import Mission
from fleetbus.workers.store.users import User

#: Who comments on any mission they see; a client comments on the missions it owns.
COMMENTERS = frozenset(
    {UserRole.ADMIN, UserRole.PLANNER, UserRole.SUPERVISOR, UserRole.OPERATOR, UserRole.CLIENT}
)
#: The longest comment, in characters.
COMMENT_MAX = 2000
#: The most comments a thread shows (the newest).
THREAD_LIMIT = 500


def may_comment(user: User, mission: Mission) -> bool:
    if user.role is UserRole.CLIENT:
        return mission.owner == user.name
    return user.role in COMMENTERS


def _not_for(user: User, mission_id: str) -> str:
    return (
        f"role {user.role.value} may not comment on mission {mission_id}; "
        "its client, planners, supervisors, operators and admins may"
    )


class MissionComments:
    def __init__(self, missions: Missions, comments: CommentStore) -> None:
        self._missions = missions
        self._comments = comments

    async def any_thread(self, mission_id: str, limit: int = THREAD_LIMIT) -> list[Comment]:
        """The mission's newest ``limit`` comments, oldest first, for a reader who may see every
        mission (the server's own shell)."""
        await self._missions.get_any(mission_id)
        return await self._comments.comments(mission_id, limit)

    async def thread(self, user: User, mission_id: str, limit: int = THREAD_LIMIT) -> list[Comment]:
        """The mission's newest ``limit`` comments, oldest first."""
        await self._missions.get(user, mission_id)
        return await self._comments.comments(mission_id, limit)

    async def add(self, user: User, mission_id: str, text: str) -> Comment:
        """``user``'s comment on the mission; refused to a role that does not comment (before the
        mission is looked at: a robot is told its role, not whose mission it is), to a client on
        another's mission, and for an empty or too long text. Nothing is stored when refused."""
        if user.role not in COMMENTERS:
            raise Forbidden(_not_for(user, mission_id))
        mission = await self._missions.get(user, mission_id)
        if not may_comment(user, mission):
            raise Forbidden(_not_for(user, mission_id))
        text = text.strip()
        if not text:
            raise BadRequest("the comment is empty")
        if len(text) > COMMENT_MAX:
            raise BadRequest(f"the comment has {len(text)} characters; at most {COMMENT_MAX}")
        return await self._comments.add_comment(
            mission_id, user.name, user.role.value, text, datetime.now(timezone.utc)
        )
