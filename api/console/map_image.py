"""The team's map as the browser shows it: a stored PGM version drawn as a PNG, and where the
map's world coordinates fall on it.

Pillow reads every PGM a robot may send (binary and plain, 8 and 16 bits, any maxval) and writes
the PNG; a map larger than ``console_map_pixels`` on a side is scaled down (the markers keep
their world coordinates, so nothing moves). A version never changes, so its PNG is made once and
the last ``console_map_cache`` are kept.
"""

from __future__ import annotations

import asyncio
import io
from collections import OrderedDict
from dataclasses import dataclass

from PIL import Image, UnidentifiedImageError

from fleetbus.api.services.maps import Maps, MapVersion


class ImageUnreadable(Exception):
    """The stored image could not be drawn; the message says why."""


def png_of(pgm: bytes, max_side: int) -> bytes:
    """The PGM ``pgm`` as an 8-bit greyscale PNG, no side longer than ``max_side``."""
    try:
        image = Image.open(io.BytesIO(pgm))
        image.load()
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as error:
        raise ImageUnreadable(f"the stored image is not a PGM Pillow can read: {error}") from error
    if image.mode != "L":  # 16-bit PGM: Pillow gives 0..65535
        image = image.point(lambda value: value * (1 / 257)).convert("L")
    if max(image.size) > max_side:
        image.thumbnail((max_side, max_side), Image.Resampling.BOX)
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=False)
    return out.getvalue()


@dataclass(frozen=True)
class Frame:
    """Where a version's image lies in the world, in metres: the lower-left pixel at the map's
    origin (map_server's YAML), the top row at origin y + height x resolution."""

    version: MapVersion
    width: int
    """Pixels of the stored image (before any scaling down)."""
    height: int

    @property
    def resolution(self) -> float:
        return float(self.version.metadata["resolution"])

    @property
    def origin(self) -> tuple[float, float, float]:
        x, y, yaw = self.version.metadata["origin"]
        return float(x), float(y), float(yaw)

    @property
    def bounds(self) -> str:
        """``west south east north`` in metres: the world rectangle the image covers (the map's
        Leaflet image overlay, in its simple CRS where a point is (y, x))."""
        x, y, _ = self.origin
        return f"{x:g} {y:g} {x + self.width * self.resolution:g} {y + self.height * self.resolution:g}"


#: Image sizes remembered (a version's size is read from its first chunk's PGM header).
SIZES_KEPT = 256


class MapImages:
    """The PNGs of the versions last shown, made on a thread (one at a time) and kept."""

    def __init__(self, maps: Maps, max_side: int, keep: int) -> None:
        self._maps = maps
        self._max_side = max_side
        self._keep = keep
        self._made: OrderedDict[int, bytes] = OrderedDict()
        self._sizes: OrderedDict[int, tuple[int, int]] = OrderedDict()
        self._lock = asyncio.Lock()

    async def frame(self, version: MapVersion) -> Frame:
        size = self._sizes.get(version.version)
        if size is None:
            size = self._sizes[version.version] = await self._maps.size(version)
            while len(self._sizes) > SIZES_KEPT:
                self._sizes.popitem(last=False)
        return Frame(version, *size)

    async def png(self, version: MapVersion) -> bytes:
        async with self._lock:
            if version.version in self._made:
                self._made.move_to_end(version.version)
                return self._made[version.version]
            pgm = await self._maps.image(version)
            made = await asyncio.to_thread(png_of, pgm, self._max_side)
            self._made[version.version] = made
            while len(self._made) > self._keep:
                self._made.popitem(last=False)
            return made
