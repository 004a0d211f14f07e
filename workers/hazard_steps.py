"""An operator takes a hazard's step for a warden: claim it, report it reached or cleared, release it.

A warden takes these steps itself with a request (``hazard.claim``...). For an operator (the
console) the step runs through the very handler of that request
(:func:`fleetbus.workers.services.hazard_services`), with the warden as the caller, so the rules
are the robot's own: a claim of an announced hazard (or of a held one while the gate is open),
the other steps only for the warden holding the claim. The broker would not let anyone else send
a request in a warden's name, and the warden would not learn of a step it did not take: so the
warden is then told, in its inbox, the hazard's new state (``hazard_state``, ``claimed_by``),
persistent and confirmed, by the default exchange as the administrator.

Only a warden in service is given a hazard, and told anything (one out of service is sent nothing;
put back, it gets the open hazards with their states).
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from datetime import datetime, timezone
from urllib.parse import unquote, urlsplit

import pika

from fleetbus.broker.direct import NoSuchQueue, NotTaken, put_in_queue
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import RobotKind, inbox_queue
from fleetbus.workers.coordination import hazard_notification
from fleetbus.workers.rpc import ServiceError
from fleetbus.workers.services import hazard_services
from fleetbus.workers.store.channels import ChannelStore
from fleetbus.workers.store.hazards import CLAIM_WHILE_OPEN, CLEAR, REACH, RELEASE, CoordinationStore, Hazard

log = logging.getLogger("fleetbus.hazards")

#: Each step an operator may take for a warden: the request it runs, and the states it starts from.
STEPS = {
    "claim": ("hazard.claim", CLAIM_WHILE_OPEN.sources),
    "reached": ("hazard.reached", REACH.sources),
    "cleared": ("hazard.cleared", CLEAR.sources),
    "release": ("hazard.release", RELEASE.sources),
}
CLAIM_STEP = "claim"


class StepRefused(Exception):
    """A step the hazard, the warden or the team does not allow; the message says why."""


@dataclass(frozen=True)
class StepTaken:
    hazard: Hazard
    """The hazard after the step."""
    not_told: str | None
    """Why the warden was not told (no inbox, the broker did not take it); None: its inbox took it."""


def steps_from(hazard: Hazard) -> list[str]:
    """The steps that may start from ``hazard``'s state (who may take them is for the step to say);
    none for a site's hazard, whose steps are taken at its site."""
    if hazard.site is not None:
        return []
    return [name for name, (_, sources) in STEPS.items() if hazard.state in sources]


async def take_step(
    hazards: CoordinationStore,
    channels: ChannelStore,
    admin_url: str,
    mission_id: str,
    hazard_id: int,
    warden: str,
    step: str,
    by: str,
) -> StepTaken:
    """Take ``step`` of hazard ``mission_id``/``hazard_id`` for ``warden`` (recorded in the log as
    done by ``by``), then tell the warden. Raises :class:`StepRefused`."""
    if step not in STEPS:
        raise StepRefused(f"no step {step!r}; steps: {', '.join(STEPS)}")
    robot = next((r for r in await hazards.robots(RobotKind.WARDEN.value) if r.name == warden), None)
    if robot is None:
        raise StepRefused(f"{warden} is not a warden of the team")
    if step == CLAIM_STEP and not robot.in_service:
        raise StepRefused(f"{warden} is out of service: put it back in service before giving it a hazard")
    request, _ = STEPS[step]
    try:
        await hazard_services(hazards, channels)[request](
            warden, {"mission_id": mission_id, "hazard_id": hazard_id}
        )
    except ServiceError as refused:
        raise StepRefused(str(refused)) from None
    hazard = await hazards.get_hazard(mission_id, hazard_id)
    assert hazard is not None  # only hazards cleared long ago are pruned: this one just took a step
    log.info("hazard %s:%d %s for %s by %s", mission_id, hazard_id, step, warden, by)
    if not robot.in_service:
        return StepTaken(hazard, f"{warden} is out of service: it is told when put back")
    note = hazard_notification(hazard, datetime.now(timezone.utc), hazard.state, None)
    return StepTaken(hazard, await asyncio.to_thread(_tell, admin_url, warden, note))


def _tell(admin_url: str, warden: str, note: Notification) -> str | None:
    """Put ``note`` in ``warden``'s inbox; why it could not, or None."""
    properties = pika.BasicProperties(
        content_type="application/json",
        message_id=f"{note.event.message_id}:{note.topic.value}:{note.hazard_state}@{warden}",
        type=note.topic.value,
        user_id=unquote(urlsplit(admin_url).username or "guest"),
    )
    try:
        put_in_queue(admin_url, inbox_queue(warden), note.model_dump_json().encode(), properties)
    except (NoSuchQueue, NotTaken) as error:
        log.warning("%s was not told of hazard %d (%s)", warden, note.hazard_id, error)
        return f"{warden} was not told: {error}"
    return None
