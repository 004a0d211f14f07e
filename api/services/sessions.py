"""Login sessions, the one way: begun at login, checked on every request, ended server-side.

A login (``POST /auth/token`` or the console's form) begins a session in the store and hands out a
token naming it; the console keeps that token in its cookie. Every request's token is checked
against the store, so a session ended by a logout, by an administrator, by a password change or
by the user's removal refuses its token at the next request. A session lasts
``FLEETBUS_API_TOKEN_MINUTES`` from its login (it is not extended by use), and a user keeps at most
``FLEETBUS_API_SESSIONS_PER_USER``: a login beyond them ends the user's oldest.
"""

from __future__ import annotations

import logging
import secrets
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from fleetbus.api.services.errors import NotFound
from fleetbus.api.services.security import Token, TokenRefused, Tokens
from fleetbus.workers.store.sessions import Session, SessionStore
from fleetbus.workers.store.users import User, UserStore

log = logging.getLogger("fleetbus.api.sessions")

#: How stale a session's "last seen" may be: a request writes it at most this often.
SEEN_EVERY = timedelta(seconds=30)
AGENT_MOST = 200


@dataclass(frozen=True)
class Origin:
    """Where a login comes from, as the user's own sessions list shows it."""

    address: str | None
    agent: str | None


class Sessions:
    def __init__(self, store: SessionStore, tokens: Tokens, per_user: int) -> None:
        self.store = store
        self._store = store
        self._tokens = tokens
        self.per_user = per_user

    async def begin(self, user: str, origin: Origin, now: datetime | None = None) -> Token:
        """A new session of ``user`` and its token (the user's oldest ends beyond the bound)."""
        now = now or datetime.now(timezone.utc)
        token = self._tokens.issue(user, now=now, session=secrets.token_urlsafe(18))
        assert token.session is not None
        session = Session(token.session, user, now, now, token.expires_at, origin.address, origin.agent)
        await self._store.prune_sessions(now)  # everyone's expired ones: nobody else deletes them
        await self._store.begin_session(session, self.per_user)
        return token

    async def check(self, value: str) -> Session:
        """The live session ``value`` (a token) belongs to; :class:`TokenRefused` saying why not."""
        token = self._tokens.read(value)
        if token.session is None:
            raise TokenRefused("the token belongs to no session; log in again")
        now = datetime.now(timezone.utc)
        session = await self._store.get_session(token.session)
        if session is None or session.user != token.subject:
            raise TokenRefused(
                "the session has ended (logged out, ended by an admin, or a password change); log in again"
            )
        if not session.live(now):
            raise TokenRefused("the session has expired; log in again")
        if now - session.last_seen >= SEEN_EVERY:  # else a read-only request writes nothing
            await self._store.session_seen(session.id, now, SEEN_EVERY)
        return session

    async def is_open(self, session_id: str) -> bool:
        """Whether the session is still stored and has not expired (an open stream asks)."""
        session = await self._store.get_session(session_id)
        return session is not None and session.live(datetime.now(timezone.utc))

    async def of(self, user: str) -> list[Session]:
        """``user``'s live sessions, newest first."""
        return await self._store.sessions_of(user, datetime.now(timezone.utc))

    async def end(self, user: str, session_id: str) -> bool:
        """End one of ``user``'s sessions; False when it has none of that id."""
        return await self._store.end_session(session_id, user)

    async def end_all(self, user: str, keep: str | None = None) -> int:
        """End every session of ``user`` (but ``keep``, the caller's own); how many ended."""
        return await self._store.end_sessions(user, keep)

    async def end_token(self, value: str) -> bool:
        """End the session a token belongs to (a logout); False when it had none or ended before.
        An expired or foreign token ends nothing."""
        try:
            token = self._tokens.read(value)
        except TokenRefused:
            return False
        return token.session is not None and await self._store.end_session(token.session, token.subject)


class UserGone(TokenRefused):
    """The session is live but its user was removed; the message names the user."""

    def __init__(self, name: str) -> None:
        super().__init__(f"user {name!r} no longer exists")
        self.name = name


class SignedIn:
    """Who a request's token signs in: the one check of the HTTP API and the console."""

    def __init__(self, sessions: Sessions, users: UserStore) -> None:
        self._sessions = sessions
        self._users = users

    async def check(self, token: str) -> tuple[Session, User]:
        """The live session ``token`` names and its user, read from the store now (so a role
        changed since the login applies); :class:`TokenRefused` saying why not, :class:`UserGone`
        when the user was removed."""
        session = await self._sessions.check(token)
        user = await self._users.get_user(session.user)
        if user is None:
            raise UserGone(session.user)
        return session, user


async def end_sessions_of(
    users: UserStore, store: SessionStore, name: str, by: str, keep: str | None = None
) -> int:
    """End every session of the user ``name`` but ``keep`` (:class:`NotFound` when there is no
    such user); how many ended. The API, the console and ``fleetbus api end-sessions`` all do it here."""
    if await users.get_user(name) is None:
        raise NotFound(f"no user {name!r}")
    ended = await store.end_sessions(name, keep)
    log.info("user %s: %d session(s) ended by %s", name, ended, by)
    return ended


class UserSessions:
    """Ending a user's sessions, for a process that begins none (the command line)."""

    def __init__(self, users: UserStore, store: SessionStore) -> None:
        self._users = users
        self._store = store

    async def end(self, name: str, by: str) -> int:
        """:func:`end_sessions_of`: every session of ``name``; how many ended."""
        return await end_sessions_of(self._users, self._store, name, by)
