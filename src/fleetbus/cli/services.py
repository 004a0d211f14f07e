"""The application services (:mod:`fleetbus.api.standalone`) for a command: the rules of the HTTP
API and the console, on the same store. Their refusals end the command with their ``detail`` (the
HTTP API's problem ``detail``) and the exit code of :data:`fleetbus.cli.accounts.EXIT_CODES`."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, TypeVar

from fleetbus.cli.accounts import EXIT_CODES
from fleetbus.cli.context import fail, settings

if TYPE_CHECKING:
    from fleetbus.api.standalone import Services

T = TypeVar("T")


def with_services(
    work: Callable[[Services], Awaitable[T]], admin_url: str | None = None, refused: str = ""
) -> T:
    """Run ``work`` with the services; ``admin_url``: the administrator's broker, for the changes
    that tell robots or the hazard service. ``refused``: put before a refusal's detail."""
    from fleetbus.api.errors import ServiceRefusal
    from fleetbus.api.standalone import open_services

    async def go() -> T:
        async with open_services(settings(), admin_url) as services:
            return await work(services)

    try:
        return asyncio.run(go())
    except ServiceRefusal as refusal:
        fail(f"{refused}{refusal.detail}", EXIT_CODES.get(refusal.status, 1))
