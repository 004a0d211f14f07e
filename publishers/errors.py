"""Errors the robot client raises; each names what the broker said."""

from __future__ import annotations


class PublisherError(Exception):
    pass


class BrokerUnavailable(PublisherError):
    """The broker could not be reached, or the connection broke before the confirms came."""


class PublishRefused(PublisherError):
    """The broker refused a message: access refused, forged user id, nack or unroutable."""


class PublishTimeout(PublisherError):
    """The broker did not confirm in time; the messages may or may not have been queued."""
