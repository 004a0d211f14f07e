"""Broker URLs as they may be shown: the one place a password is masked before a URL is printed or logged."""

from __future__ import annotations

from urllib.parse import urlsplit, urlunsplit

MASK = "****"


def _replace_password(url: str, password: str | None) -> str:
    parts = urlsplit(url)
    if parts.password is None:
        return url
    userinfo, _, hostinfo = parts.netloc.rpartition("@")
    user = userinfo.partition(":")[0]
    netloc = f"{user}@{hostinfo}" if password is None else f"{user}:{password}@{hostinfo}"
    return urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


def mask_password(url: str) -> str:
    """``amqp://user:****@host:5672/vhost`` for ``amqp://user:secret@host:5672/vhost``; a URL
    without a password is returned as it is."""
    return _replace_password(url, MASK)


def without_password(url: str) -> str:
    """``amqp://user@host:5672/vhost``: for whoever finds the password elsewhere (a kept file)."""
    return _replace_password(url, None)
