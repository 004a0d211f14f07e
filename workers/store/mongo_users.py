"""Users on MongoDB (one document per user, ``_id`` = name), one repository of `mongo_repositories`."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pymongo import ASCENDING, ReturnDocument
from pymongo.errors import DuplicateKeyError

from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.base import from_micros, to_micros
from fleetbus.workers.store.mongo_database import OnMongo, translate_unavailable
from fleetbus.workers.store.users import NoSuchUser, User, UserExists, UserStore


def _user(doc: dict[str, Any]) -> User:
    return User(
        name=doc["_id"],
        role=UserRole(doc["role"]),
        password_hash=doc.get("password_hash"),
        broker_secret=doc.get("broker_secret"),
        kind=doc.get("kind"),
        created_at=from_micros(doc["created_at_us"]),
        created_by=doc["created_by"],
        updated_at=from_micros(doc["updated_at_us"]),
    )


@translate_unavailable(UserStore)
class MongoUsers(OnMongo, UserStore):
    async def add_user(self, user: User) -> None:
        try:
            await self._collection("users").insert_one(
                {
                    "_id": user.name,
                    "role": user.role.value,
                    "password_hash": user.password_hash,
                    "broker_secret": user.broker_secret,
                    "kind": user.kind,
                    "created_at_us": to_micros(user.created_at),
                    "created_by": user.created_by,
                    "updated_at_us": to_micros(user.updated_at),
                }
            )
        except DuplicateKeyError:
            raise UserExists(f"user {user.name!r} exists") from None

    async def get_user(self, name: str) -> User | None:
        doc = await self._collection("users").find_one({"_id": name})
        return _user(doc) if doc else None

    async def users(self, role: UserRole | None = None) -> list[User]:
        query = {} if role is None else {"role": role.value}
        return [_user(doc) async for doc in self._collection("users").find(query).sort("_id", ASCENDING)]

    async def update_user(
        self,
        name: str,
        at: datetime,
        *,
        role: UserRole | None = None,
        password_hash: str | None = None,
        broker_secret: str | None = None,
    ) -> User:
        changes: dict[str, Any] = {"updated_at_us": to_micros(at)}
        for field, value in (
            ("role", role.value if role else None),
            ("password_hash", password_hash),
            ("broker_secret", broker_secret),
        ):
            if value is not None:
                changes[field] = value
        doc = await self._collection("users").find_one_and_update(
            {"_id": name}, {"$set": changes}, return_document=ReturnDocument.AFTER
        )
        if doc is None:
            raise NoSuchUser(f"no user {name!r}")
        return _user(doc)

    async def remove_user(self, name: str) -> bool:
        result = await self._collection("users").delete_one({"_id": name})
        return result.deleted_count == 1
