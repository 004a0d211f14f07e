"""Which routing keys the recorder keeps: include and exclude patterns, in topic syntax."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fleetbus.schemas.topics import topic_matches


@dataclass(frozen=True)
class RoutingFilter:
    """Keep a key that matches an include pattern (any key when there are none) and no exclude pattern.

    Patterns are AMQP topic patterns: ``explorer1.#``, ``*.map_chunk``, ``notify.*``.
    """

    include: Sequence[str] = ()
    exclude: Sequence[str] = ()

    def keeps(self, routing_key: str) -> bool:
        if self.include and not any(topic_matches(pattern, routing_key) for pattern in self.include):
            return False
        return not any(topic_matches(pattern, routing_key) for pattern in self.exclude)
