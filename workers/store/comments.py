"""Each mission's discussion: the comments of its client, planners, supervisors and operators,
in the order they were stored (``serial``: two comments of the same microsecond keep it)."""

from __future__ import annotations

import abc
import uuid
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from fleetbus.workers.store.port import SERIAL, TEXT, TIME, Database, Doc, Index, Range, Schema


@dataclass(frozen=True)
class Comment:
    number: int
    """The comment's number in the store: the order comments were stored in (across missions)."""
    mission_id: str
    author: str
    role: str
    """The author's role when it wrote the comment."""
    text: str
    at: datetime

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "at": self.at.isoformat()}


class CommentStore(abc.ABC):
    @abc.abstractmethod
    async def add_comment(self, mission_id: str, author: str, role: str, text: str, at: datetime) -> Comment:
        """Store a comment; it is the newest of its mission's."""

    @abc.abstractmethod
    async def comments(self, mission_id: str, limit: int | None = None, after: int = 0) -> list[Comment]:
        """The mission's comments numbered above ``after``, oldest first; with ``limit``, the
        newest ``limit`` of them (still oldest first)."""

    @abc.abstractmethod
    async def count_comments(self, mission_id: str) -> int: ...


COMMENTS = Schema(
    "mission_comments",
    {"once": TEXT, "mission_id": TEXT, "author": TEXT, "role": TEXT, "text": TEXT, "at": TIME},
    serial=True,
    indexes=(Index("once", unique=True), Index("mission_id", SERIAL)),
)
"""``once``: a random id the comment is read back by (an insert names no serial number back)."""


def _comment(doc: Doc) -> Comment:
    return Comment(doc[SERIAL], doc["mission_id"], doc["author"], doc["role"], doc["text"], doc["at"])


class Comments(CommentStore):
    def __init__(self, database: Database) -> None:
        self._comments = database.collection(COMMENTS)

    async def add_comment(self, mission_id: str, author: str, role: str, text: str, at: datetime) -> Comment:
        once = uuid.uuid4().hex
        doc = {"once": once, "mission_id": mission_id, "author": author, "role": role, "text": text, "at": at}
        await self._comments.insert([doc])
        found = await self._comments.find({"once": once}, limit=1)
        return _comment(found[0])

    async def comments(self, mission_id: str, limit: int | None = None, after: int = 0) -> list[Comment]:
        where = {"mission_id": mission_id, SERIAL: Range(gt=after)} if after else {"mission_id": mission_id}
        found = await self._comments.find(where, order=["-" + SERIAL], limit=limit)
        return [_comment(doc) for doc in reversed(found)]

    async def count_comments(self, mission_id: str) -> int:
        return await self._comments.count({"mission_id": mission_id})
