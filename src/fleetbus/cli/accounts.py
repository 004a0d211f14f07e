"""The accounts service (:class:`fleetbus.api.services.accounts.Accounts`) for a command: the rules of the
HTTP API and the console, on the same registry and broker. Its refusals end the command with their
``detail`` (the HTTP API's problem ``detail``) and an exit code: 2 for bad input, 1 otherwise."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, TypeVar

from fleetbus.cli.context import settings

if TYPE_CHECKING:
    from fleetbus.api.services.accounts import Accounts
    from fleetbus.broker.endpoint import BrokerEndpoint
    from fleetbus.broker.management import ManagementAPI
    from fleetbus.workers.store import Repositories

T = TypeVar("T")

#: The exit code of each refusal's HTTP status (bad input as a usage error; the rest 1).
EXIT_CODES = {422: 2}


def with_accounts(
    ep: BrokerEndpoint, work: Callable[[Accounts, Repositories, ManagementAPI], Awaitable[T]]
) -> T:
    """Run ``work`` with the accounts service, the repositories and the management API it uses."""
    from fleetbus.api.services.accounts import open_accounts
    from fleetbus.cli.services import run_service

    async def go() -> T:
        async with open_accounts(settings(), ep.amqp_url, ep.management_url, ep.public_url) as opened:
            return await work(opened.accounts, opened.repositories, opened.management)

    return run_service(go)
