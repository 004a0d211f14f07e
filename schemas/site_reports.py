"""What a site tells central about itself (``fleetbus site apply`` sends it every
``FLEETBUS_SITE_REPORT_EVERY_S``): what waits in its uplink and how its shovels fare, at a time."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict

SITE_REPORT_TYPE = "fleetbus.site-report"


class SiteReport(BaseModel):
    model_config = ConfigDict(extra="forbid")

    site: str
    at: datetime
    """When the site measured it (its clock)."""
    waiting: int | None
    """Events in the site's uplink not yet confirmed by central; None when it could not tell."""
    uplink: str
    """The uplink shovel's state (``running``, ``starting``, ``terminated``, ``absent``)."""
    downlink: str
    rejected: int | None = None
    """Downlink messages the site could not apply."""
    hazard_states_waiting: int | None = None
    """Hazard states made at the site not yet confirmed by central (in ``fleetbus.hazard-uplink``);
    None when it could not tell, or the site's fleetbus is older."""
    hazard_uplink: str | None = None
    """The hazard states' shovel's state; None from an older site."""
