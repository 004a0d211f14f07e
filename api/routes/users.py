"""Users and roles: admins manage everyone; supervisors see the robots; everyone sees themself.

Login sessions: everyone lists and ends their own (``/users/me/sessions``); an admin lists and
ends anyone's (``/users/{name}/sessions``). An ended session's token is refused at its next request."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Response

from fleetbus.api.auth import ServiceDep, current_session, require_role
from fleetbus.api.models import (
    PasswordChange,
    PasswordSet,
    RegistryCheck,
    RoleChange,
    SessionOut,
    SessionsEnded,
    UseCasesSet,
    UserCreate,
    UserOut,
)
from fleetbus.api.openapi import refusals
from fleetbus.api.services.accounts import User
from fleetbus.api.services.errors import BadRequest, Conflict, NotFound
from fleetbus.api.services.sessions import Session
from fleetbus.schemas.roles import ACTIVE_ROLES, UserRole

router = APIRouter(tags=["users"])
R = UserRole
Anyone = Annotated[User, Depends(require_role(*ACTIVE_ROLES))]
Admin = Annotated[User, Depends(require_role(R.ADMIN))]
AdminOrSupervisor = Annotated[User, Depends(require_role(R.ADMIN, R.SUPERVISOR))]
Current = Annotated[Session, Depends(current_session)]


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
async def change_my_password(
    body: PasswordChange, user: Anyone, session: Current, svc: ServiceDep
) -> Response:
    """Change your password; your other sessions end (this one goes on)."""
    await svc.accounts.change_own_password(user, body.current_password, body.new_password, keep=session.id)
    return Response(status_code=204)


@router.get("/users/me/sessions", response_model=list[SessionOut])
async def my_sessions(user: Anyone, session: Current, svc: ServiceDep) -> list[SessionOut]:
    """Your login sessions (console logins and API tokens), newest first; ``current`` is this one."""
    return [SessionOut.of(s, session) for s in await svc.sessions.of(user.name)]


@router.delete("/users/me/sessions/{session_id}", status_code=204)
async def end_my_session(session_id: str, user: Anyone, svc: ServiceDep) -> Response:
    """End one of your sessions (this one too: that is a logout); its token is refused from now on."""
    if not await svc.sessions.end(user.name, session_id):
        raise NotFound(f"you have no session {session_id!r} (it may have ended already)")
    return Response(status_code=204)


@router.get("/users", response_model=list[UserOut])
async def list_users(user: AdminOrSupervisor, svc: ServiceDep, role: UserRole | None = None) -> list[UserOut]:
    """Every user for an admin; the robots for a supervisor."""
    return [UserOut.of(u) for u in await svc.accounts.listed(user, role)]


@router.post("/users", response_model=UserOut, status_code=201, responses=refusals(Conflict))
async def create_user(body: UserCreate, admin: Admin, svc: ServiceDep) -> UserOut:
    """A new user (``inactive`` unless a role is given) and its broker account."""
    return UserOut.of(await svc.accounts.create(body.name, body.password, body.role, body.kind, admin.name))


@router.get("/users/{name}", response_model=UserOut)
async def get_user(name: str, user: AdminOrSupervisor, svc: ServiceDep) -> UserOut:
    return UserOut.of(await svc.accounts.seen(user, name))


@router.put("/users/{name}/role", response_model=UserOut)
async def set_role(name: str, body: RoleChange, admin: Admin, svc: ServiceDep) -> UserOut:
    """Change a user's role; its broker account follows (``inactive``: no broker access at all)."""
    return UserOut.of(await svc.accounts.set_role(name, body.role, admin.name))


@router.put("/users/{name}/use-cases", response_model=UserOut)
async def set_use_cases(name: str, body: UseCasesSet, admin: Admin, svc: ServiceDep) -> UserOut:
    """Set the use cases the user may create missions of (null: every one); a mission of another
    is refused with 403. As `fleetbus users use-cases NAME --allow ...`."""
    return UserOut.of(await svc.accounts.set_use_cases(name, body.use_cases, admin.name))


@router.put("/users/{name}/password", status_code=204)
async def reset_password(
    name: str, body: PasswordSet, admin: Admin, session: Current, svc: ServiceDep
) -> Response:
    """Set the user's password; every session of the user ends (the admin's own goes on)."""
    await svc.accounts.set_password(name, body.password, keep=session.id if name == admin.name else None)
    return Response(status_code=204)


@router.get("/users/{name}/sessions", response_model=list[SessionOut])
async def user_sessions(name: str, admin: Admin, session: Current, svc: ServiceDep) -> list[SessionOut]:
    """The user's login sessions, newest first."""
    await svc.accounts.get(name)
    return [SessionOut.of(s, session) for s in await svc.sessions.of(name)]


@router.delete("/users/{name}/sessions", response_model=SessionsEnded)
async def end_user_sessions(name: str, admin: Admin, session: Current, svc: ServiceDep) -> SessionsEnded:
    """End every session of the user (an admin ending its own keeps the one it sends this with):
    its console logins and API tokens are refused from the next request on. As `fleetbus api
    end-sessions NAME`."""
    keep = session.id if name == admin.name else None
    return SessionsEnded(user=name, ended=await svc.accounts.end_sessions(name, admin.name, keep=keep))


@router.delete("/users/{name}", status_code=204, responses=refusals(BadRequest, Conflict))
async def remove_user(name: str, admin: Admin, svc: ServiceDep) -> Response:
    """Remove the user and its broker account."""
    if name == admin.name:
        raise BadRequest("an admin cannot remove itself")
    await svc.accounts.remove(name, admin.name)
    return Response(status_code=204)
