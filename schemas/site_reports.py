"""What a site tells central about itself (``fleetbus site apply`` sends it every
``FLEETBUS_SITE_REPORT_EVERY_S``): what waits in its uplink and how its shovels fare, at a time."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field

SITE_REPORT_TYPE = "fleetbus.site-report"


class UplinkDepth(BaseModel):
    """What waits in one class of the site's uplink, and its bound."""

    model_config = ConfigDict(extra="forbid")

    waiting: int = Field(ge=0)
    bound: int = Field(ge=1)
    overflow: str
    """``reject-publish`` (full: the site refuses the robots' events of the class) or ``drop-head``."""

    @property
    def share(self) -> float:
        return self.waiting / self.bound


class SiteReport(BaseModel):
    model_config = ConfigDict(extra="forbid")

    site: str
    at: datetime
    """When the site measured it (its clock)."""
    waiting: int | None
    """Events in the site's uplink not yet confirmed by central, every class; None when it could
    not tell."""
    classes: dict[str, UplinkDepth] | None = None
    """Each class of the uplink (hazards, events, telemetry): what waits and its bound; None from
    an older site."""
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
    accounts: list[str] | None = None
    """The robots whose accounts central gave the site and the site still has (those whose events
    it forwards, with an account on its broker; not the robots made at the site alone), sorted:
    central finds copies the site should no longer have. None from an older site."""
    in_use: dict[str, str] | None = None
    """Of ``accounts``, those in use at the site (a robot mounted there), with why: a copy central
    asked the site to remove stays while it is. None from an older site."""
