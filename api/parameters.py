"""Path and query parameters the REST routes and the console's pages share."""

from __future__ import annotations

from typing import Annotated

from fastapi import Path

from fleetbus.api.services.hazards import LARGEST_INTEGER

#: A hazard's id in a path: the store numbers each mission's hazards from 1.
HazardId = Annotated[int, Path(ge=1, le=LARGEST_INTEGER, description="the hazard's id within its mission")]
