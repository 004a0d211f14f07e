"""The one rule for user and robot names.

A name is also a RabbitMQ user name and the prefix of every exchange and queue that user owns
(``<name>.events``, ``<name>.inbox``), so it may not contain a dot or anything a broker pattern
would read as a wildcard.
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator, WithJsonSchema

NAME_PATTERN = re.compile(r"^[a-z][a-z0-9_-]{1,31}$")
RESERVED_PREFIXES = ("fleetbus", "amq", "guest")


def validate_name(name: str) -> str:
    """Return ``name`` if it may be a fleetbus user or robot name, else raise ``ValueError``."""
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(
            f"invalid name {name!r}: use 2-32 characters, lower-case letters, digits, '-' or '_', "
            "starting with a letter"
        )
    if name.startswith(RESERVED_PREFIXES):
        raise ValueError(f"invalid name {name!r}: names starting with {RESERVED_PREFIXES} are reserved")
    return name


RobotId = Annotated[
    str,
    AfterValidator(validate_name),
    WithJsonSchema(
        {
            "type": "string",
            "pattern": NAME_PATTERN.pattern,
            "description": "an account name, not starting with " + ", ".join(RESERVED_PREFIXES),
        }
    ),
]
