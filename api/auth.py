"""Who is calling, and may they: the dependencies every router uses.

    @router.post("/users", dependencies=[...])
    async def create(user: User = Depends(require_role(UserRole.ADMIN))): ...

:func:`current_user` turns the bearer token into the stored user (401 when there is no valid
token, or its login session has ended or expired); :func:`require_role` then admits only the
given roles (403 otherwise). Both log each refusal on ``fleetbus.api.services.security``. ``inactive`` is
never admitted.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import OAuth2PasswordBearer

from fleetbus.api import audit
from fleetbus.api.service import Service
from fleetbus.api.services.security import TokenRefused
from fleetbus.api.services.sessions import UserGone
from fleetbus.schemas.roles import UserRole
from fleetbus.workers.store.sessions import Session
from fleetbus.workers.store.users import User

bearer = OAuth2PasswordBearer(tokenUrl="/auth/token", auto_error=False)


def service(request: Request) -> Service:
    return request.app.state.service


ServiceDep = Annotated[Service, Depends(service)]


def unauthorized(request: Request, why: str, who: str = "(anonymous)") -> HTTPException:
    audit.refused(request, 401, who, why)
    return HTTPException(401, detail=why, headers={"WWW-Authenticate": "Bearer"})


async def current_user(
    request: Request, svc: ServiceDep, token: Annotated[str | None, Depends(bearer)]
) -> User:
    if not token:
        raise unauthorized(
            request, "not logged in: send 'Authorization: Bearer <token>' from POST /auth/token"
        )
    try:
        session, user = await svc.signed_in.check(token)
    except UserGone as gone:
        raise unauthorized(request, str(gone), who=gone.name) from None
    except TokenRefused as refused:
        raise unauthorized(request, str(refused)) from None
    request.state.user = user  # for the refusal log of later checks
    request.state.session = session  # the caller's own, for the routes on its sessions
    return user


def current_session(request: Request) -> Session:
    """The caller's session, once :func:`current_user` (a role check) admitted it."""
    return request.state.session


class RoleCheck:
    """A dependency admitting the listed roles; routes carrying one list them in the OpenAPI document."""

    def __init__(self, roles: frozenset[UserRole]) -> None:
        self.roles = roles

    async def __call__(self, request: Request, user: Annotated[User, Depends(current_user)]) -> User:
        if user.role not in self.roles:
            needs = " or ".join(sorted(role.value for role in self.roles))
            why = f"role {user.role.value} may not do this; it needs {needs}"
            if user.role is UserRole.INACTIVE:
                why = "role inactive may not do anything; an admin must give the account a role"
            audit.refused(request, 403, f"{user.name} ({user.role.value})", why)
            raise HTTPException(403, detail=why)
        return user


def require_role(*roles: UserRole) -> RoleCheck:
    """Admit only callers with one of ``roles`` (``inactive`` never)."""
    return RoleCheck(frozenset(roles) - {UserRole.INACTIVE})
