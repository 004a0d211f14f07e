"""Where the broker routes a message now: its exchanges, bindings and consumers, as data.

Built from the management API (:meth:`RouteMap.from_management`), then asked without the
broker: :meth:`RouteMap.routes` follows exchange-to-exchange bindings the way RabbitMQ does
(direct: equal keys; topic: patterns; fanout: everything; the default exchange: the queue
named by the key; an exchange that routes nowhere: its alternate exchange) and names the
consumers each queue has.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.topics import topic_matches

UNREPORTED = "user not reported by the broker yet"


@dataclass(frozen=True)
class Consumer:
    user: str | None
    """The consuming connection's login; None while the management API has not reported it (it
    lists a consumer before its channel's statistics, which can lag by seconds)."""
    connection: str | None

    @property
    def label(self) -> str:
        return self.user if self.user is not None else f"a consumer ({UNREPORTED})"


@dataclass(frozen=True)
class Route:
    queue: str
    via: tuple[str, ...]
    """The exchanges the message passes on its way to the queue, first the one it was published to."""
    consumers: tuple[Consumer, ...]


@dataclass(frozen=True)
class Binding:
    source: str
    destination: str
    to_exchange: bool
    routing_key: str


class RouteMap:
    def __init__(
        self,
        exchange_types: Mapping[str, str],
        bindings: Iterable[Binding],
        consumers: Mapping[str, Iterable[Consumer]],
        alternates: Mapping[str, str] | None = None,
    ) -> None:
        self._types = dict(exchange_types)
        self._alternates = dict(alternates or {})
        self._bindings: dict[str, list[Binding]] = {}
        for binding in bindings:
            self._bindings.setdefault(binding.source, []).append(binding)
        self._consumers = {queue: tuple(found) for queue, found in consumers.items()}

    @classmethod
    def from_management(cls, api: ManagementAPI, vhost: str) -> RouteMap:
        listed = api.list_exchanges(vhost)
        exchanges = {e["name"]: e["type"] for e in listed}
        alternates = {
            e["name"]: e["arguments"]["alternate-exchange"]
            for e in listed
            if (e.get("arguments") or {}).get("alternate-exchange")
        }
        bindings = [
            Binding(b["source"], b["destination"], b["destination_type"] == "exchange", b["routing_key"])
            for b in api.list_bindings(vhost)
            if b["source"]  # the default exchange's implicit bindings are handled by name
        ]
        consumers: dict[str, list[Consumer]] = {}
        for consumer in api.list_consumers(vhost):
            details: dict[str, Any] = consumer.get("channel_details") or {}
            consumers.setdefault(consumer["queue"]["name"], []).append(
                Consumer(details.get("user"), details.get("connection_name"))
            )
        return cls(exchanges, bindings, consumers, alternates)

    def keys_into(self, queue: str, source: str) -> list[str]:
        """The binding keys by which ``source`` feeds ``queue`` (an inbox's subscriptions)."""
        return sorted(
            b.routing_key
            for b in self._bindings.get(source, [])
            if b.destination == queue and not b.to_exchange
        )

    def _matches(self, exchange: str, binding: Binding, routing_key: str) -> bool:
        kind = self._types.get(exchange, "topic")
        if kind == "fanout":
            return True
        if kind == "topic":
            return topic_matches(binding.routing_key, routing_key)
        if kind == "direct":
            return binding.routing_key == routing_key
        return False  # headers exchanges route on headers, which a route map does not see

    def routes(self, exchange: str, routing_key: str) -> list[Route]:
        """The queues a message published now to ``exchange`` with ``routing_key`` would reach."""
        if exchange == "":
            return [Route(routing_key, ("(default)",), self._consumers.get(routing_key, ()))]
        found: dict[str, Route] = {}
        pending: list[tuple[str, tuple[str, ...]]] = [(exchange, (exchange,))]
        visited = set()
        while pending:
            current, via = pending.pop(0)
            if current in visited:
                continue
            visited.add(current)
            matched = [b for b in self._bindings.get(current, []) if self._matches(current, b, routing_key)]
            alternate = self._alternates.get(current)
            if not matched and alternate:
                pending.append((alternate, (*via, alternate)))
            for binding in matched:
                if binding.to_exchange:
                    pending.append((binding.destination, (*via, binding.destination)))
                elif binding.destination not in found:
                    found[binding.destination] = Route(
                        binding.destination, via, self._consumers.get(binding.destination, ())
                    )
        return sorted(found.values(), key=lambda route: route.queue)
