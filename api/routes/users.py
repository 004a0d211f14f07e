"""Users and roles: admins manage everyone; supervisors see the robots; everyone sees themself."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Response

from fleetbus.api.auth import ServiceDep, UsersDep, require_role
from fleetbus.api.errors import BadRequest, Conflict, Forbidden, NotFound
from fleetbus.api.models import (
    PasswordChange,
    PasswordSet,
    RegistryCheck,
    RoleChange,
    UserCreate,
    UserOut,
)
from fleetbus.api.openapi import refusals
from fleetbus.schemas.roles import ACTIVE_ROLES, UserRole
from fleetbus.workers.store.users import User

router = APIRouter(tags=["users"])
R = UserRole
Anyone = Annotated[User, Depends(require_role(*ACTIVE_ROLES))]
Admin = Annotated[User, Depends(require_role(R.ADMIN))]
AdminOrSupervisor = Annotated[User, Depends(require_role(R.ADMIN, R.SUPERVISOR))]


@router.get("/registry/drift", response_model=RegistryCheck, tags=["registry"])
async def registry_drift(admin: Admin, svc: ServiceDep) -> RegistryCheck:
    """What differs between the account registry and the broker's accounts, permissions, topic
    permissions and shard bindings, the team and the sites' accounts (`fleetbus users check`)."""
    return RegistryCheck.of([], await svc.account_check.drift())


@router.post("/registry/repair", response_model=RegistryCheck, tags=["registry"])
async def registry_repair(admin: Admin, svc: ServiceDep) -> RegistryCheck:
    """Repair every drift (`fleetbus users check --repair`): what was repaired, and what is left."""
    repaired = await svc.account_check.repair(admin.name)
    return RegistryCheck.of(repaired, await svc.account_check.drift())


@router.get("/users/me", response_model=UserOut)
async def me(user: Anyone) -> UserOut:
    return UserOut.of(user)


@router.put("/users/me/password", status_code=204, responses=refusals(NotFound))
async def change_my_password(body: PasswordChange, user: Anyone, svc: ServiceDep) -> Response:
    if not await svc.secrets.passwords.verify(user.password_hash, body.current_password):
        raise BadRequest("the current password is wrong")
    await svc.accounts.set_password(user.name, body.new_password)
    return Response(status_code=204)


@router.get("/users", response_model=list[UserOut])
async def list_users(user: AdminOrSupervisor, users: UsersDep, role: UserRole | None = None) -> list[UserOut]:
    """Every user for an admin; the robots for a supervisor."""
    if user.role is R.SUPERVISOR:
        if role not in (None, R.ROBOT):
            raise Forbidden("a supervisor sees robots only")
        role = R.ROBOT
    return [UserOut.of(u) for u in await users.users(role)]


@router.post("/users", response_model=UserOut, status_code=201, responses=refusals(Conflict))
async def create_user(body: UserCreate, admin: Admin, svc: ServiceDep) -> UserOut:
    """A new user (``inactive`` unless a role is given) and its broker account."""
    return UserOut.of(await svc.accounts.create(body.name, body.password, body.role, body.kind, admin.name))


@router.get("/users/{name}", response_model=UserOut)
async def get_user(name: str, user: AdminOrSupervisor, svc: ServiceDep) -> UserOut:
    found = await svc.accounts.get(name)
    if user.role is R.SUPERVISOR and found.role is not R.ROBOT:
        raise Forbidden("a supervisor sees robots only")
    return UserOut.of(found)


@router.put("/users/{name}/role", response_model=UserOut)
async def set_role(name: str, body: RoleChange, admin: Admin, svc: ServiceDep) -> UserOut:
    """Change a user's role; its broker account follows (``inactive``: no broker access at all)."""
    return UserOut.of(await svc.accounts.set_role(name, body.role, admin.name))


@router.put("/users/{name}/password", status_code=204)
async def reset_password(name: str, body: PasswordSet, admin: Admin, svc: ServiceDep) -> Response:
    await svc.accounts.set_password(name, body.password)
    return Response(status_code=204)


@router.delete("/users/{name}", status_code=204, responses=refusals(BadRequest, Conflict))
async def remove_user(name: str, admin: Admin, svc: ServiceDep) -> Response:
    """Remove the user and its broker account."""
    if name == admin.name:
        raise BadRequest("an admin cannot remove itself")
    await svc.accounts.remove(name, admin.name)
    return Response(status_code=204)
