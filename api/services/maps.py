"""Which stored versions of the team's map a user may see: the one rule for every image of it.

The watchers (admins, supervisors, operators) follow the team on the live map: every stored
version. Authors (clients and planners) may not see where the team is; they draw a mission's
plan on the team's map, so they see its newest version only, the one the new mission form shows.
No other role sees the map. The server's own tools (the command line) see every version
(:class:`Maps`).
"""

from __future__ import annotations

from fleetbus.api.services.errors import Forbidden, NotFound
from fleetbus.api.services.missions import AUTHORS
from fleetbus.schemas.pgm import read_pgm_header
from fleetbus.schemas.roles import WATCHERS
from fleetbus.workers.maps import map_image, missing_version
from fleetbus.workers.store.maps import MapStore, MapVersion
from fleetbus.workers.store.users import User

__all__ = ["MapVersion", "Maps", "map_version_for"]


async def map_version_for(maps: MapStore, user: User, version: int | None) -> MapVersion:
    """The stored ``version`` (the newest for None) if ``user`` may see it; else NotFound (no
    such version) or Forbidden (an author asking for another than the newest)."""
    if user.role not in WATCHERS | AUTHORS:
        raise Forbidden(f"role {user.role.value} may not see the team's map")
    found = await _stored(maps, version)
    if user.role in WATCHERS or version is None:
        return found
    newest = await maps.map_version(None)
    if newest is not None and newest.version != found.version:
        raise Forbidden(
            f"{user.name} is {user.role.value}: clients and planners see the newest map version "
            f"only ({newest.version}), to draw a mission's plan on"
        )
    return found


async def _stored(maps: MapStore, version: int | None) -> MapVersion:
    """The stored ``version`` (the newest for None); NotFound saying why there is none."""
    found = await maps.map_version(version)
    if found is None:
        raise NotFound(await missing_version(maps, version))
    return found


class Maps:
    """The stored versions of the team's map: every one for the server's own tools (the command
    line) and the console's images of a version already chosen; :meth:`visible` for a user."""

    def __init__(self, maps: MapStore) -> None:
        self._maps = maps

    async def versions(self) -> list[MapVersion]:
        """Every stored version, newest first."""
        return await self._maps.map_versions()

    async def newest(self) -> MapVersion | None:
        """The newest stored version; None before the first."""
        return await self._maps.map_version(None)

    async def version(self, version: int | None) -> MapVersion:
        """The stored ``version`` (the newest for None); NotFound saying why there is none."""
        return await _stored(self._maps, version)

    async def image(self, version: MapVersion) -> bytes:
        """The version's whole PGM file."""
        return await map_image(self._maps, version)

    async def visible(self, user: User, version: int | None) -> MapVersion:
        """The stored ``version`` if ``user`` may see it (:func:`map_version_for`)."""
        return await map_version_for(self._maps, user, version)

    async def size(self, version: MapVersion) -> tuple[int, int]:
        """The version's image's width and height in pixels, read from its first chunk's header."""
        header = read_pgm_header(await self._maps.map_chunk(version.version, 0))
        return header.width, header.height
