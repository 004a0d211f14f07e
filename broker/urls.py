"""Broker URLs as they may be shown: the one place a password is masked before a URL is printed or logged."""

from __future__ import annotations

import re
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


#: A password in a URL anywhere in a text: ``scheme://user:PASSWORD@``.
URL_PASSWORD = re.compile(r"(?P<start>[a-z][a-z0-9+.-]*://[^:/@\s\"']*:)[^@\s\"']*@", re.IGNORECASE)


def masked_in_text(text: str) -> str:
    """``text`` (an error a server sent, say) with the password of every URL in it masked."""
    return URL_PASSWORD.sub(rf"\g<start>{MASK}@", text)


def without_password(url: str) -> str:
    """``amqp://user@host:5672/vhost``: for whoever finds the password elsewhere (a kept file)."""
    return _replace_password(url, None)
