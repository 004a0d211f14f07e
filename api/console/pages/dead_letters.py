"""Dead letters: what the workers (or the broker, or the recorder) refused, each with why and the
message itself, as ``fleetbus dlq`` lists it; how many the full queue dropped. Administrators
requeue or discard one (:mod:`fleetbus.broker.dead_letter_actions`).

Reading takes the letters and puts them back in their order, as ``fleetbus dlq`` does; a
requeue publishes the message again as the account that sent it, with that account's broker
password from the accounts service, so the broker checks it as it did the first time.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Annotated
from urllib.parse import urlencode

import pika.exceptions
from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import ADMINS, DEAD_LETTERS
from fleetbus.api.console.templating import render
from fleetbus.api.service import Service
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import NotFound, ServiceRefusal
from fleetbus.bounds import bounds
from fleetbus.broker.dead_letter_actions import (
    DeadLetterGone,
    RemovalUnconfirmed,
    RequeueRefused,
    discard_dead_letter,
    requeue_dead_letter,
)
from fleetbus.broker.dead_letter_queue import DeadLetter, Listing

log = logging.getLogger("fleetbus.api.console")
router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(DEAD_LETTERS))]
Requeuer = Annotated[User, Depends(Allowed(ADMINS, "requeue dead letters"))]
Discarder = Annotated[User, Depends(Allowed(ADMINS, "discard dead letters"))]

NOTICES = {
    "requeued": "Dead letter {letter} was published again as its sender and removed from the queue.",
    "discarded": "Dead letter {letter} was discarded.",
}
BROKER_FAILURES = (pika.exceptions.AMQPError, OSError)


@dataclass(frozen=True)
class Shown:
    letter: DeadLetter
    body: str
    """The body as text, up to ``console_dead_letter_body`` bytes."""
    more: int
    """Bytes of the body not shown."""


def _shown(letter: DeadLetter, limit: int) -> Shown:
    return Shown(letter, letter.body[:limit].decode(errors="replace"), max(0, letter.size - limit))


async def _page(
    request: Request,
    user: User,
    svc: Service,
    status_code: int = 200,
    problem: str | None = None,
    notice: str | None = None,
) -> Response:
    settings = svc.settings
    listing: Listing | None = None
    try:
        listing = await svc.dead_letter_queue.listing(settings.console_dead_letters)
    except BROKER_FAILURES as error:
        unread = f"the dead-letter queue cannot be read ({type(error).__name__}: {error})"
        problem = f"{problem}; {unread}" if problem else unread
        status_code = 503
    letters = listing.letters if listing else []
    return render(
        request,
        "dead_letters/page.html",
        user,
        DEAD_LETTERS,
        status_code=status_code,
        letters=[_shown(letter, settings.console_dead_letter_body) for letter in letters],
        in_queue=listing.in_queue if listing else None,
        dropped=await svc.dead_letter_queue.dropped(),
        kept=bounds(settings).dead_letters.describe(),
        can_change=user.role in ADMINS,
        problem=problem,
        notice=notice,
    )


@router.get("/console/dead-letters", response_class=HTMLResponse)
async def dead_letters(
    request: Request, user: Viewer, svc: ServiceDep, done: str | None = None, letter: str | None = None
) -> Response:
    notice = NOTICES[done].format(letter=letter) if done in NOTICES and letter else None
    return await _page(request, user, svc, notice=notice)


async def _sender_url(svc: Service, user_id: str) -> str:
    """The AMQP URL of the account that sent a letter, logged in as itself."""
    try:
        user = await svc.accounts.get(user_id)
    except NotFound:
        raise RequeueRefused(
            f"{user_id} is not an account of the service: its broker password is unknown here, so its "
            "message cannot be published again as it"
        ) from None
    try:
        return svc.accounts.internal_broker_url(user)
    except (ServiceRefusal, ValueError) as error:
        raise RequeueRefused(f"{user_id}'s broker password cannot be had: {error}") from None


def _done(done: str, letter_id: str) -> RedirectResponse:
    return RedirectResponse(f"/console/dead-letters?{urlencode({'done': done, 'letter': letter_id})}", 303)


@router.post("/console/dead-letters/{letter_id}/requeue", response_class=HTMLResponse)
async def requeue(request: Request, letter_id: str, admin: Requeuer, svc: ServiceDep) -> Response:
    loop = asyncio.get_running_loop()

    def sender_url(user_id: str) -> str:  # asked from the broker's thread; the store is on this loop
        return asyncio.run_coroutine_threadsafe(_sender_url(svc, user_id), loop).result(60)

    try:
        letter = await asyncio.to_thread(requeue_dead_letter, svc.admin_url, letter_id, sender_url)
    except DeadLetterGone as gone:
        return await _page(request, admin, svc, 409, problem=str(gone))
    except (RequeueRefused, RemovalUnconfirmed) as refused:
        return await _page(request, admin, svc, 502, problem=str(refused))
    except BROKER_FAILURES as error:
        return await _page(request, admin, svc, 503, problem=f"nothing was requeued: {error!r}")
    log.info(
        "dead letter %s (message %s from %s) requeued to %s by %s",
        letter_id,
        letter.message_id,
        letter.user_id,
        letter.exchange,
        admin.name,
    )
    return _done("requeued", letter_id)


@router.post("/console/dead-letters/{letter_id}/discard", response_class=HTMLResponse)
async def discard(request: Request, letter_id: str, admin: Discarder, svc: ServiceDep) -> Response:
    try:
        letter = await asyncio.to_thread(discard_dead_letter, svc.admin_url, letter_id)
    except DeadLetterGone as gone:
        return await _page(request, admin, svc, 409, problem=str(gone))
    except BROKER_FAILURES as error:
        return await _page(request, admin, svc, 503, problem=f"nothing was discarded: {error!r}")
    log.info(
        "dead letter %s (message %s from %s, %s) discarded by %s",
        letter_id,
        letter.message_id,
        letter.user_id,
        letter.reason,
        admin.name,
    )
    return _done("discarded", letter_id)
