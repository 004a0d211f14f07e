"""Passwords, tokens and the one stored secret, each with a well-kept library.

- Passwords: argon2id (argon2-cffi), salted; only the hash is stored. Hashing and checking run
  on threads of their own, a bounded number at once, never on the event loop.
- Tokens: JWT (PyJWT, HS256) with ``sub``, ``iat``, ``exp`` and ``sid``, the login session it
  belongs to; an expired, tampered or foreign token is refused, and so is one whose session has
  ended (:mod:`fleetbus.api.services.sessions`). The caller's role is read from the store on every request,
  never trusted from the token, so a role change or removal takes effect at once.
- Broker passwords: the login reply must hand them back, so they are stored encrypted (Fernet:
  AES-128-CBC with HMAC-SHA256) under a key derived from the service's master secret.
"""

from __future__ import annotations

import asyncio
import base64
import secrets
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import jwt
from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from cryptography.fernet import Fernet, InvalidToken
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from fleetbus.broker.accounts import save_secret_once
from fleetbus.settings import Settings

TOKEN_ALGORITHM = "HS256"
TOKEN_ISSUER = "fleetbus"
MIN_PASSWORD_LENGTH = 10


def master_secret(settings: Settings) -> bytes:
    """``FLEETBUS_API_SECRET``, else a random secret kept in ``data_dir/api/secret`` (mode 0600).
    API processes starting at once all end with the first one written (see :func:`save_secret_once`)."""
    if settings.api_secret:
        return settings.api_secret.get_secret_value().encode()
    path = settings.api_dir / "secret"
    if not path.exists():
        save_secret_once(path, secrets.token_urlsafe(48))
    return path.read_text().strip().encode()


def derive_key(secret: bytes, purpose: str) -> bytes:
    """A 32-byte key for one purpose, so the token key and the encryption key never coincide."""
    return HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=purpose.encode()).derive(secret)


class Passwords:
    """argon2id, computed on ``concurrency`` threads of its own. A hash costs tens of milliseconds
    of CPU (argon2 releases the GIL): on the event loop, a burst of logins would hold up every
    other request; on unbounded threads, it would take every core."""

    def __init__(self, concurrency: int = 1, memory_kib: int = 65536) -> None:
        self._hasher = PasswordHasher(memory_cost=memory_kib)
        self._threads = ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="fleetbus-argon2")
        # verifying against this when the user does not exist takes as long as a real check
        self._dummy = self._hasher.hash(secrets.token_urlsafe(16))

    async def hash(self, password: str) -> str:
        return await asyncio.get_running_loop().run_in_executor(self._threads, self._hasher.hash, password)

    async def verify(self, password_hash: str | None, password: str) -> bool:
        return await asyncio.get_running_loop().run_in_executor(
            self._threads, self._verify, password_hash, password
        )

    def _verify(self, password_hash: str | None, password: str) -> bool:
        try:
            return self._hasher.verify(password_hash or self._dummy, password) and password_hash is not None
        except (VerificationError, InvalidHashError):
            return False

    def close(self) -> None:
        self._threads.shutdown(wait=False, cancel_futures=True)


def password_problem(password: str) -> str | None:
    if len(password) < MIN_PASSWORD_LENGTH:
        return f"the password must have at least {MIN_PASSWORD_LENGTH} characters"
    if len(password) > 256:
        return "the password must have at most 256 characters"
    return None


class TokenRefused(Exception):
    """Why a token cannot be accepted; the message is what the caller is told."""


@dataclass(frozen=True)
class Token:
    value: str
    subject: str
    expires_at: datetime
    session: str | None = None
    """The login session the token belongs to (``sid``)."""


class Tokens:
    def __init__(self, key: bytes, lifetime: timedelta) -> None:
        self._key = key
        self.lifetime = lifetime

    def issue(
        self,
        subject: str,
        now: datetime | None = None,
        lifetime: timedelta | None = None,
        session: str | None = None,
    ) -> Token:
        """A signed token; it admits nobody until a session ``session`` of ``subject`` is stored
        (:meth:`fleetbus.api.services.sessions.Sessions.begin` does both)."""
        issued = now or datetime.now(timezone.utc)
        expires = issued + (lifetime if lifetime is not None else self.lifetime)
        claims = {
            "sub": subject,
            "iss": TOKEN_ISSUER,
            "iat": int(issued.timestamp()),
            "exp": int(expires.timestamp()),
            "jti": secrets.token_hex(8),
        }
        if session is not None:
            claims["sid"] = session
        value = jwt.encode(claims, self._key, algorithm=TOKEN_ALGORITHM)
        return Token(value, subject, expires, session)

    def read(self, value: str) -> Token:
        """The token's subject, expiry and session, when it is ours and has not expired; raise
        :class:`TokenRefused` saying why not."""
        try:
            claims = jwt.decode(
                value,
                self._key,
                algorithms=[TOKEN_ALGORITHM],
                issuer=TOKEN_ISSUER,
                options={"require": ["sub", "iat", "exp", "iss"]},
            )
        except jwt.ExpiredSignatureError:
            raise TokenRefused("the token has expired; log in again") from None
        except jwt.InvalidSignatureError:
            raise TokenRefused("the token's signature is not valid (tampered with, or not ours)") from None
        except jwt.InvalidTokenError as error:
            raise TokenRefused(f"the token is not valid: {error}") from None
        session = claims.get("sid")
        expires = datetime.fromtimestamp(claims["exp"], timezone.utc)
        return Token(value, str(claims["sub"]), expires, session if isinstance(session, str) else None)


class SecretBox:
    """Encrypts the broker passwords kept in the store (and one on its way to the console's page)."""

    def __init__(self, key: bytes) -> None:
        self._fernet = Fernet(base64.urlsafe_b64encode(key))

    def seal(self, plain: str) -> str:
        return self._fernet.encrypt(plain.encode()).decode()

    def open(self, sealed: str, max_age_s: int | None = None) -> str:
        """The plain text; ``max_age_s``: refused when sealed longer ago than that."""
        try:
            return self._fernet.decrypt(sealed.encode(), ttl=max_age_s).decode()
        except InvalidToken:
            if max_age_s is not None:
                raise ValueError(f"sealed more than {max_age_s} s ago, or not by this service") from None
            raise ValueError(
                "the stored broker password cannot be decrypted with this service's secret"
            ) from None


@dataclass(frozen=True)
class Secrets:
    passwords: Passwords
    tokens: Tokens
    box: SecretBox

    @classmethod
    def for_settings(cls, settings: Settings) -> Secrets:
        secret = master_secret(settings)
        return cls(
            Passwords(settings.api_hash_threads, settings.api_hash_memory_kib),
            Tokens(derive_key(secret, "fleetbus api tokens"), timedelta(minutes=settings.api_token_minutes)),
            SecretBox(derive_key(secret, "fleetbus broker passwords")),
        )
