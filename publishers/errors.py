"""Errors the robot client raises; each names what the broker said."""

from __future__ import annotations


class PublisherError(Exception):
    pass


class BrokerUnavailable(PublisherError):
    """The broker could not be reached (or found, or started), or the connection broke before the
    confirms came; the message says which, and what to do. One class for the robot client and the
    server side alike."""


class LoginRefused(BrokerUnavailable):
    """The broker refused the robot's login: its credentials (a wrong or changed password, an
    account removed) or its access to the virtual host. Trying again does not help until they are
    fixed on the robot or on the broker; the message names the robot, never the password."""


class ClientClosed(PublisherError):
    """The robot client was closed: it opens no more connections to call the services or listen."""


class PublishRefused(PublisherError):
    """The broker refused a message: access refused, forged user id, nack or unroutable."""


class PublishTimeout(PublisherError):
    """The broker did not confirm in time; the messages may or may not have been queued."""


def _connection_failures() -> tuple[type[Exception], ...]:
    import pika.exceptions
    from pika.adapters.utils.connection_workflow import AMQPConnectorException

    return (pika.exceptions.AMQPConnectionError, AMQPConnectorException)


#: What ``pika.BlockingConnection(...)`` raises when it could not connect. With one connection attempt
#: (pika's default) pika raises the connector's own error, a handshake timeout on a loaded broker
#: say, which is no ``AMQPError``: catch this tuple, not ``AMQPError``, around opening a connection.
CONNECTION_FAILED: tuple[type[Exception], ...] = _connection_failures()
