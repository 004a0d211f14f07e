"""Login sessions of the service layer: one per login (the console's cookie, an API bearer token).

A token names its session; a request is admitted only while the session is stored and has not
expired, so deleting a session (a logout, an administrator ending a user's sessions, a password
change, the user's removal) refuses its token at once, wherever it is held. A user keeps at most
a bounded number: beginning one more ends the oldest.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from datetime import datetime, timedelta

from fleetbus.workers.store.port import TEXT, TIME, Database, Doc, In, Index, Ne, Range, Schema


@dataclass(frozen=True)
class Session:
    id: str
    user: str
    begun_at: datetime
    last_seen: datetime
    expires_at: datetime
    address: str | None
    """The client's address at login, when known."""
    agent: str | None
    """The client's User-Agent at login, when it sent one."""

    def live(self, now: datetime) -> bool:
        return self.expires_at > now


class SessionStore(abc.ABC):
    @abc.abstractmethod
    async def begin_session(self, session: Session, most: int) -> list[str]:
        """Store ``session``; then end its user's expired sessions and, of the live ones, all but
        the ``most`` newest. The ids of the sessions ended."""

    @abc.abstractmethod
    async def get_session(self, session_id: str) -> Session | None: ...

    @abc.abstractmethod
    async def sessions_of(self, user: str, now: datetime) -> list[Session]:
        """``user``'s sessions live at ``now``, newest first."""

    @abc.abstractmethod
    async def session_seen(self, session_id: str, at: datetime, every: timedelta) -> None:
        """Set the session's last sighting to ``at`` unless it was set less than ``every`` before
        (a request does not write the store each time)."""

    @abc.abstractmethod
    async def end_session(self, session_id: str, user: str) -> bool:
        """Delete ``user``'s session ``session_id``; False when it has none of that id."""

    @abc.abstractmethod
    async def end_sessions(self, user: str, keep: str | None = None) -> int:
        """Delete every session of ``user`` but ``keep``; how many."""

    @abc.abstractmethod
    async def prune_sessions(self, now: datetime) -> int:
        """Delete every session expired at ``now``; how many."""


SESSIONS = Schema(
    "sessions",
    {
        "id": TEXT,
        "user_name": TEXT,
        "begun_at": TIME,
        "last_seen": TIME,
        "expires_at": TIME,
        "address": TEXT.maybe,
        "agent": TEXT.maybe,
    },
    key=("id",),
    indexes=(Index("user_name", "begun_at"), Index("expires_at")),
)


def _session(doc: Doc) -> Session:
    fields = dict(doc)
    return Session(user=fields.pop("user_name"), **fields)


def _doc(session: Session) -> Doc:
    fields = dict(session.__dict__)
    return {"user_name": fields.pop("user"), **fields}


class Sessions(SessionStore):
    """Each step is atomic on its own (an insert, a delete by id): beginning a session is one
    transaction on SQLite, and on MongoDB two logins at once each keep the newest ``most``."""

    def __init__(self, database: Database) -> None:
        self._database = database
        self._sessions = database.collection(SESSIONS)

    async def begin_session(self, session: Session, most: int) -> list[str]:
        async def begin() -> list[str]:
            await self._sessions.insert([_doc(session)])
            mine = await self._sessions.find(
                {"user_name": session.user}, order=["-begun_at", "-id"], fields=["id", "expires_at"]
            )
            live = [doc["id"] for doc in mine if doc["expires_at"] > session.begun_at]
            ended = [doc["id"] for doc in mine if doc["expires_at"] <= session.begun_at] + live[most:]
            if ended:
                await self._sessions.delete({"id": In(ended)})
            return ended

        return await self._database.transaction(begin)

    async def get_session(self, session_id: str) -> Session | None:
        doc = await self._sessions.get(session_id)
        return _session(doc) if doc else None

    async def sessions_of(self, user: str, now: datetime) -> list[Session]:
        found = await self._sessions.find(
            {"user_name": user, "expires_at": Range(gt=now)}, order=["-begun_at", "-id"]
        )
        return [_session(doc) for doc in found]

    async def session_seen(self, session_id: str, at: datetime, every: timedelta) -> None:
        await self._sessions.update({"id": session_id, "last_seen": Range(le=at - every)}, {"last_seen": at})

    async def end_session(self, session_id: str, user: str) -> bool:
        return await self._sessions.delete({"id": session_id, "user_name": user}) == 1

    async def end_sessions(self, user: str, keep: str | None = None) -> int:
        where = {"user_name": user} if keep is None else {"user_name": user, "id": Ne(keep)}
        return await self._sessions.delete(where)

    async def prune_sessions(self, now: datetime) -> int:
        return await self._sessions.delete({"expires_at": Range(le=now)})
