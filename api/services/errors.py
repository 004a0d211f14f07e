"""What the services refuse, as exceptions: the HTTP API answers each with its status as a problem
whose ``detail`` is the exception's (:mod:`fleetbus.api.problems`); the command line and the
console show the same ``detail``."""

from __future__ import annotations


class ServiceRefusal(Exception):
    status = 400

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class BadRequest(ServiceRefusal):
    status = 422


class NotFound(ServiceRefusal):
    status = 404


class Forbidden(ServiceRefusal):
    status = 403


class Conflict(ServiceRefusal):
    status = 409


class Unavailable(ServiceRefusal):
    status = 503


def unavailable(error: BaseException) -> Unavailable | None:
    """What the HTTP API answers 503 to and the command line says, for a part of the system that
    failed under a service (the store, the broker's management API); None for anything else."""
    import httpx

    from fleetbus.broker.management import ManagementError
    from fleetbus.workers.store.base import StoreUnavailable

    if isinstance(error, StoreUnavailable):
        return Unavailable(f"the store is unavailable: {error}")
    if isinstance(error, ManagementError):
        return Unavailable(f"the broker's management API failed: {error}")
    if isinstance(error, httpx.TransportError):
        # the only HTTP the services make is to the broker's management API
        return Unavailable(f"the broker's management API is unreachable: {error}")
    return None
