"""Tell the hazard service that the team changed: a message on the express lane itself.

The hazard service runs where the express lane is consumed, by its single active consumer, so a
team change that can open the gate (a warden taken out of service or removed) or owes a warden
hazards (put back in service) is handled there, in turn with the hazards and localisations, by
the one party that announces. The store is changed first; this message makes the service look.
"""

from __future__ import annotations

import uuid

import pika

from fleetbus.broker.direct import NoSuchQueue, NotTaken, put_in_queue
from fleetbus.schemas.routing import EXPRESS_QUEUE
from fleetbus.schemas.team import TEAM_CHANGE_TYPE, TeamChange


class HazardServiceNotTold(RuntimeError):
    """The broker did not take the team change; the message says what to do."""


def tell_hazard_service(admin_url: str, change: TeamChange) -> None:
    """Put ``change`` on the express lane, persistent and confirmed (the default exchange)."""
    properties = pika.BasicProperties(
        content_type="application/json",
        message_id=f"team-change-{uuid.uuid4().hex}",
        type=TEAM_CHANGE_TYPE,
    )
    retry = (
        f"the team change is stored; repeat the command to tell the hazard service ({change.change.value})"
    )
    try:
        put_in_queue(admin_url, EXPRESS_QUEUE, change.model_dump_json().encode(), properties)
    except NoSuchQueue as error:
        raise HazardServiceNotTold(
            f"there is no express lane ({EXPRESS_QUEUE}) on this broker yet: start a worker"
        ) from error
    except NotTaken as error:
        raise HazardServiceNotTold(f"{error}: {retry}") from error
