"""A mission's discussion over HTTP: its thread, and a comment added to it."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, Query
from pydantic import BaseModel, ConfigDict, Field

from fleetbus.api.auth import ServiceDep, require_role
from fleetbus.api.openapi import refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import BadRequest
from fleetbus.api.services.mission_comments import COMMENT_MAX, COMMENTERS, THREAD_LIMIT, Comment
from fleetbus.schemas.roles import UserRole

router = APIRouter(tags=["missions"])
Reader = Annotated[User, Depends(require_role(*COMMENTERS, UserRole.GUEST))]
Commenter = Annotated[User, Depends(require_role(*COMMENTERS))]


class CommentIn(BaseModel):
    model_config = ConfigDict(extra="forbid")

    # the bound is the service's (the command line and the console are held to it too): said here
    text: str = Field(
        description=f"the comment: 1 to {COMMENT_MAX} characters, not only white space",
        json_schema_extra={"minLength": 1, "maxLength": COMMENT_MAX},
    )


class CommentOut(BaseModel):
    number: int = Field(description="the comment's number: comments are listed in its order")
    mission_id: str
    author: str
    role: UserRole = Field(description="the author's role when it commented")
    text: str
    at: datetime = Field(description="when it was stored (UTC)")

    @classmethod
    def of(cls, comment: Comment) -> CommentOut:
        return cls(
            number=comment.number,
            mission_id=comment.mission_id,
            author=comment.author,
            role=UserRole(comment.role),
            text=comment.text,
            at=comment.at,
        )


@router.get("/missions/{mission_id}/comments", response_model=list[CommentOut])
async def list_comments(
    mission_id: str,
    user: Reader,
    svc: ServiceDep,
    limit: Annotated[int, Query(ge=1, le=THREAD_LIMIT)] = THREAD_LIMIT,
) -> list[CommentOut]:
    """The mission's discussion, oldest first (the newest `limit` comments): whoever may see the
    mission reads it (a client its own missions)."""
    return [CommentOut.of(c) for c in await svc.mission_comments.thread(user, mission_id, limit)]


@router.post(
    "/missions/{mission_id}/comments",
    response_model=CommentOut,
    status_code=201,
    responses=refusals(BadRequest),
)
async def add_comment(mission_id: str, body: CommentIn, user: Commenter, svc: ServiceDep) -> CommentOut:
    """Comment on the mission: its client, planners, supervisors, operators and admins may
    (a guest reads only). 422: the text is empty or longer than the bound."""
    return CommentOut.of(await svc.mission_comments.add(user, mission_id, body.text))
