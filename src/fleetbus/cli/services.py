"""The application services (:mod:`fleetbus.api.services.standalone`) for a command: the rules of the HTTP
API and the console, on the same store and recording. Their refusals end the command with their
``detail`` (the HTTP API's problem ``detail``) and the exit code of
:data:`fleetbus.cli.accounts.EXIT_CODES`."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine, Iterator
from contextlib import AsyncExitStack, contextmanager
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

from fleetbus.cli.accounts import EXIT_CODES
from fleetbus.cli.context import fail, settings

if TYPE_CHECKING:
    from fleetbus.api.services.errors import ServiceRefusal
    from fleetbus.api.services.recording import Recording
    from fleetbus.api.services.standalone import Services

T = TypeVar("T")


def fail_refused(refusal: ServiceRefusal, before: str = "") -> NoReturn:
    """End the command with a service's refusal: its detail (``before`` put first), its exit code."""
    fail(f"{before}{refusal.detail}", EXIT_CODES.get(refusal.status, 1))


def run_service(go: Callable[[], Coroutine[Any, Any, T]], before: str = "") -> T:
    """Run a service call to its end: a refusal, or a part of the system that failed under it (the
    store, the broker's management API), ends the command with what the HTTP API would answer."""
    from fleetbus.api.services.errors import ServiceRefusal, unavailable

    try:
        return asyncio.run(go())
    except ServiceRefusal as refusal:
        fail_refused(refusal, before)
    except Exception as error:
        if (down := unavailable(error)) is None:
            raise
        fail_refused(down, before)


def with_services(
    work: Callable[[Services], Awaitable[T]], admin_url: str | None = None, refused: str = ""
) -> T:
    """Run ``work`` with the services; ``admin_url``: the administrator's broker, for the changes
    that tell robots or the hazard service. ``refused``: put before a refusal's detail."""
    from fleetbus.api.services.standalone import open_services

    async def go() -> T:
        async with open_services(settings(), admin_url) as services:
            return await work(services)

    return run_service(go, refused)


def with_recording(work: Callable[[Recording], Awaitable[T]], events: bool = False) -> T:
    """Run ``work`` with the recording the settings select; ``events``: with the event log too."""
    from fleetbus.api.services.standalone import open_recording

    async def go() -> T:
        async with open_recording(settings(), events) as recording:
            return await work(recording)

    return run_service(go)


@contextmanager
def recording_stream(open_stream: Callable[[Recording], AsyncIterator[T]]) -> Iterator[Iterator[T]]:
    """Open the recording and iterate ``open_stream(recording)`` from synchronous code (pika's
    blocking publishing, say), one item at a time on an event loop of its own; closed on leaving.
    A refusal comes out of the iteration (:class:`~fleetbus.api.services.errors.ServiceRefusal`): the
    command ends it with :func:`fail_refused` once what it was writing is cleaned up."""
    from fleetbus.api.services.standalone import open_recording

    loop = asyncio.new_event_loop()
    opened = AsyncExitStack()
    stream: AsyncIterator[T] | None = None
    try:
        recording = loop.run_until_complete(opened.enter_async_context(open_recording(settings())))
        stream = open_stream(recording)

        def items() -> Iterator[T]:
            assert stream is not None
            while True:
                try:
                    yield loop.run_until_complete(anext(stream))
                except StopAsyncIteration:
                    return

        yield items()
    finally:
        if stream is not None and hasattr(stream, "aclose"):
            loop.run_until_complete(stream.aclose())
        loop.run_until_complete(opened.aclose())
        loop.close()
