"""AMQP topic patterns as RabbitMQ reads them: ``*`` is one word, ``#`` is zero or more words."""

from __future__ import annotations

from functools import lru_cache


@lru_cache(maxsize=1024)
def _words(text: str) -> tuple[str, ...]:
    return tuple(text.split(".")) if text else ()


def topic_matches(pattern: str, routing_key: str) -> bool:
    """Whether a topic exchange would route ``routing_key`` through a binding with ``pattern``."""
    return _match(_words(pattern), _words(routing_key))


@lru_cache(maxsize=8192)
def _match(pattern: tuple[str, ...], words: tuple[str, ...]) -> bool:
    if not pattern:
        return not words
    head, rest = pattern[0], pattern[1:]
    if head == "#":
        # zero words, or one more word still under the same '#'
        return _match(rest, words) or (bool(words) and _match(pattern, words[1:]))
    if not words:
        return False
    return (head == "*" or head == words[0]) and _match(rest, words[1:])
