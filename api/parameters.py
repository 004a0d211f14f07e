"""Path and query parameters the REST routes and the console's pages share."""

from __future__ import annotations

from typing import Annotated

from fastapi import Path

from fleetbus.api.services.hazards import LARGEST_INTEGER

#: A hazard's id in a path: the store numbers each mission's hazards from 1.
HazardId = Annotated[int, Path(ge=1, le=LARGEST_INTEGER, description="the hazard's id within its mission")]
#: An alert's id in a path (numbered from 1).
AlertId = Annotated[int, Path(ge=1, le=LARGEST_INTEGER, description="the alert's id")]
#: A stored map version in a path (numbered from 1); beyond the store's integers, a 422, not a 500.
MapVersionNumber = Annotated[int, Path(ge=1, le=LARGEST_INTEGER, description="a stored map version")]
