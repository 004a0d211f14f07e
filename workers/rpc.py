"""Request/reply over AMQP: robots call the service, the service answers by direct reply-to.

A request is published by a robot to its own ``<robot>.requests`` exchange with the routing key
``<robot>.<method>``, ``reply_to = amq.rabbitmq.reply-to``, a correlation id and an expiration.
The broker-validated ``user_id`` is the caller. Replies are JSON: ``{"ok": true, "result": ...}``,
``{"ok": false, "error": "..."}`` for a request the service refuses (the caller's to fix: a
request that breaks the contract, not JSON by its ``content_type`` or its body, not from the robot
it names, is refused so before any service sees it, and counted), or
``{"ok": false, "error": "...", "internal": true}`` when the service failed on it (a bug: logged
with its traceback and a reference the reply repeats, and counted; not the caller's fault).
"""

from __future__ import annotations

import json
import logging
import uuid
from collections.abc import Awaitable, Callable
from typing import Any

import aio_pika
from aio_pika.abc import AbstractChannel, AbstractIncomingMessage, AbstractQueue

from fleetbus.schemas.properties import content_type_problem
from fleetbus.workers.notifier import CONFIRM_TIMEOUT_S

log = logging.getLogger("fleetbus.rpc")

Handler = Callable[[str, dict[str, Any]], Awaitable[Any]]


class ServiceError(Exception):
    """A request the service refuses; the message goes back to the caller as the error."""


class RpcServer:
    def __init__(self, channel: AbstractChannel, queue: AbstractQueue, handlers: dict[str, Handler]) -> None:
        self._channel = channel
        self._queue = queue
        self._handlers = handlers
        self._tag: str | None = None
        self.internal_errors = 0
        """Requests a handler failed on unexpectedly (each logged with its traceback)."""
        self.bad_requests = 0
        """Requests refused for breaking the contract before any handler saw them."""

    async def start(self) -> None:
        self._tag = await self._queue.consume(self._on_request)

    async def stop(self) -> None:
        if self._tag is not None and not self._channel.is_closed:
            await self._queue.cancel(self._tag)

    def _bad(self, error: str) -> dict[str, Any]:
        self.bad_requests += 1  # counted, not logged: a robot sending many would flood the log
        return {"ok": False, "error": error}

    async def answer(self, message: AbstractIncomingMessage) -> dict[str, Any]:
        caller = message.user_id or ""
        robot, _, method = (message.routing_key or "").partition(".")
        if not caller or robot != caller:
            return self._bad(f"requests must come from the robot they name ({robot!r} != {caller!r})")
        if problem := content_type_problem(message.content_type, "service requests"):
            return self._bad(problem)
        handler = self._handlers.get(method)
        if handler is None:
            return self._bad(f"no service {method!r}; services: {', '.join(sorted(self._handlers))}")
        try:
            params = json.loads(message.body or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            return self._bad(f"parameters are not JSON: {error}")
        if not isinstance(params, dict):
            return self._bad("parameters must be a JSON object")
        try:
            return {"ok": True, "result": await handler(caller, params)}
        except ServiceError as error:
            return {"ok": False, "error": str(error)}
        except Exception:
            reference = uuid.uuid4().hex[:12]
            self.internal_errors += 1
            log.exception("service %r failed on a request from %s (reference %s)", method, caller, reference)
            return {
                "ok": False,
                "internal": True,
                "error": f"the service failed on {method!r}, not through your request's fault "
                f"(reference {reference})",
            }

    async def _on_request(self, message: AbstractIncomingMessage) -> None:
        async with message.process(requeue=False):
            if not message.reply_to:  # no answer could reach its caller: not handled at all
                self.bad_requests += 1
                log.warning(
                    "request %s from %s has no reply_to; dropped", message.routing_key, message.user_id
                )
                return
            reply = await self.answer(message)
            await self._channel.default_exchange.publish(
                aio_pika.Message(
                    json.dumps(reply, default=str).encode(),
                    content_type="application/json",
                    correlation_id=message.correlation_id,
                ),
                routing_key=message.reply_to,
                mandatory=False,
                timeout=CONFIRM_TIMEOUT_S,
            )
