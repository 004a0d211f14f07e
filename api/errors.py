"""What the services refuse, as exceptions that become HTTP answers with a plain ``detail``."""

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
