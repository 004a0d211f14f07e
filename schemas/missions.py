"""A mission's plan (geofence, points of interest, itinerary, risk assessment) and its states.

Coordinates are metres in the team's map frame, like every pose on the bus. The plan is checked
as a whole: every point of interest and every itinerary stop must lie inside the geofence, and
an itinerary stop that names a point of interest must name one that exists.
"""

from __future__ import annotations

from typing import Literal

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, model_validator

from fleetbus.schemas.identity import NAME_PATTERN
from fleetbus.schemas.mission_states import MissionState

__all__ = ["MissionState"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Point(_Strict):
    x: float
    y: float


class Geofence(_Strict):
    """A single connected area every robot must stay in: a simple polygon, vertices in order."""

    frame_id: str = "map"
    polygon: list[Point] = Field(min_length=3)

    @model_validator(mode="after")
    def _has_area(self) -> Geofence:
        if abs(_signed_area(self.polygon)) < 1e-9:
            raise ValueError("the geofence polygon has no area (its vertices are on one line)")
        return self

    def contains(self, point: Point) -> bool:
        """Ray casting; a point on the boundary counts as inside."""
        inside = False
        vertices = self.polygon
        for a, b in _edges(vertices):
            if _on_segment(point, a, b):
                return True
            if (a.y > point.y) != (b.y > point.y):
                crossing = a.x + (point.y - a.y) * (b.x - a.x) / (b.y - a.y)
                if point.x < crossing:
                    inside = not inside
        return inside


def _edges(vertices: list[Point]) -> list[tuple[Point, Point]]:
    return list(zip(vertices, [*vertices[1:], vertices[0]], strict=True))


def _signed_area(vertices: list[Point]) -> float:
    return sum(a.x * b.y - b.x * a.y for a, b in _edges(vertices)) / 2


def _on_segment(p: Point, a: Point, b: Point) -> bool:
    cross = (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
    return (
        abs(cross) < 1e-9
        and min(a.x, b.x) - 1e-9 <= p.x <= max(a.x, b.x) + 1e-9
        and min(a.y, b.y) - 1e-9 <= p.y <= max(a.y, b.y) + 1e-9
    )


class PointOfInterest(_Strict):
    name: str = Field(min_length=1, max_length=80)
    x: float
    y: float
    note: str = ""


class ItineraryStop(_Strict):
    """One task: where (a point of interest by name, or coordinates), what, and when."""

    action: str = Field(min_length=1, max_length=200)
    point_of_interest: str | None = None
    x: float | None = None
    y: float | None = None
    at: AwareDatetime | None = None

    @model_validator(mode="after")
    def _one_place(self) -> ItineraryStop:
        has_xy = self.x is not None and self.y is not None
        if (self.point_of_interest is None) == (not has_xy):
            raise ValueError("give either point_of_interest or both x and y")
        return self


class RiskAssessment(_Strict):
    level: Literal["low", "medium", "high"]
    summary: str = Field(min_length=1, max_length=2000)
    mitigations: list[str] = []


class MissionPlan(_Strict):
    """What a client and a planner fill in while the mission is in planning."""

    site: str | None = Field(
        default=None,
        pattern=NAME_PATTERN.pattern,
        description="the site the mission belongs to: it goes to that site only; none: to every site",
    )
    geofence: Geofence | None = None
    points_of_interest: list[PointOfInterest] = []
    itinerary: list[ItineraryStop] = []
    risk_assessment: RiskAssessment | None = None

    @model_validator(mode="after")
    def _consistent(self) -> MissionPlan:
        problems = self.problems()
        if problems:
            raise ValueError("; ".join(problems))
        return self

    def problems(self) -> list[str]:
        found: list[str] = []
        names = [poi.name for poi in self.points_of_interest]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            found.append(f"points_of_interest: names used twice: {', '.join(duplicates)}")
        pois = {poi.name: poi for poi in self.points_of_interest}
        for index, stop in enumerate(self.itinerary):
            if stop.point_of_interest is not None and stop.point_of_interest not in pois:
                found.append(f"itinerary.{index}: no point of interest named {stop.point_of_interest!r}")
        if self.geofence is not None:
            for index, poi in enumerate(self.points_of_interest):
                if not self.geofence.contains(Point(x=poi.x, y=poi.y)):
                    found.append(
                        f"points_of_interest.{index} {poi.name!r} ({poi.x}, {poi.y}) is outside the geofence"
                    )
            for index, stop in enumerate(self.itinerary):
                if stop.x is not None and stop.y is not None:
                    if not self.geofence.contains(Point(x=stop.x, y=stop.y)):
                        found.append(f"itinerary.{index} ({stop.x}, {stop.y}) is outside the geofence")
        return found
