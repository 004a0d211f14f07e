"""The bindings a mount creates, and how to read them back from the broker.

Mounting robot R for operator O binds two channels, both made by the service with the
administrator's rights (neither O nor R may bind them itself)::

    R.events   --#-->    O.stream     the robot's data reaches the operator's queue
    O.commands --R.#-->  R.commands   the operator's commands reach the robot

Unmounting removes both. :func:`mount_bindings_on_broker` reads the broker's actual bindings of
these two shapes so the service can compare them with the mounts it has recorded.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.routing import commands_exchange, commands_queue, events_exchange, stream_queue


@dataclass(frozen=True, order=True)
class QueueBinding:
    source: str
    queue: str
    routing_key: str

    def __str__(self) -> str:
        return f"{self.source} --{self.routing_key}--> {self.queue}"


def mount_bindings(robot: str, operator: str) -> tuple[QueueBinding, QueueBinding]:
    return (
        QueueBinding(events_exchange(robot), stream_queue(operator), "#"),
        QueueBinding(commands_exchange(operator), commands_queue(robot), f"{robot}.#"),
    )


def _is_mount_binding(binding: dict[str, Any]) -> bool:
    if binding.get("destination_type") != "queue":
        return False
    source, destination = binding.get("source", ""), binding.get("destination", "")
    data = source.endswith(".events") and destination.endswith(".stream")
    commands = source.endswith(".commands") and destination.endswith(".commands")
    return data or commands


def mount_bindings_on_broker(api: ManagementAPI, vhost: str) -> set[QueueBinding]:
    return {
        QueueBinding(b["source"], b["destination"], b["routing_key"])
        for b in api.list_bindings(vhost)
        if _is_mount_binding(b)
    }


def bind_all(api: ManagementAPI, vhost: str, bindings: Iterable[QueueBinding]) -> None:
    for binding in bindings:
        api.bind(vhost, binding.source, binding.queue, binding.routing_key)


def unbind_all(api: ManagementAPI, vhost: str, bindings: Iterable[QueueBinding]) -> None:
    for binding in bindings:
        api.unbind(vhost, binding.source, binding.queue, binding.routing_key)
