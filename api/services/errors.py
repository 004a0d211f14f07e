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
