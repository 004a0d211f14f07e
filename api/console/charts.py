"""Charts as server-side SVG: the geometry of a bar chart and of a time series, in pixels, for
``templates/charts.html`` to draw.

Written here rather than taken from a charting library: the console's Content-Security-Policy
admits no inline ``style`` (attribute or element) and no inline script, which SVG renderers such
as pygal or matplotlib's SVG backend emit on every element; and what the console draws (bars
with a whisker, a step line over time, their axes) takes only scales and tick choice.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

WIDTH = 640
#: Room around the plot for the axes' ticks and labels.
LEFT, RIGHT, TOP, BOTTOM = 130, 24, 12, 46
BAR_ROW = 28
TIME_STEPS = (
    timedelta(seconds=10),
    timedelta(seconds=30),
    timedelta(minutes=1),
    timedelta(minutes=5),
    timedelta(minutes=10),
    timedelta(minutes=15),
    timedelta(minutes=30),
    timedelta(hours=1),
    timedelta(hours=3),
    timedelta(hours=6),
    timedelta(hours=12),
    timedelta(days=1),
    timedelta(days=7),
)
EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


@dataclass(frozen=True)
class Box:
    """The plot's area inside the SVG."""

    left: float
    top: float
    width: float
    height: float

    @property
    def right(self) -> float:
        return self.left + self.width

    @property
    def bottom(self) -> float:
        return self.top + self.height


def px(value: float) -> float:
    """A coordinate, to a tenth of a pixel (shorter markup, no visible difference)."""
    return round(value, 1)


@dataclass(frozen=True)
class Tick:
    at: float
    """Pixels along its axis."""
    label: str


def nice_ticks(highest: float, count: int = 5) -> list[float]:
    """0 and round steps (1, 2 or 5 times a power of ten) up to at least ``highest``."""
    if highest <= 0 or not math.isfinite(highest):
        return [0.0, 1.0]
    raw = highest / count
    power = 10 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 5, 10) if m * power >= raw)
    steps = math.ceil(highest / step - 1e-9)
    return [round(i * step, 12) for i in range(steps + 1)]


def number(value: float) -> str:
    """A tick's label: no trailing zeros, thousands grouped."""
    if value == int(value):
        return f"{int(value):,}"
    return f"{value:,.6g}"


@dataclass(frozen=True)
class Bar:
    label: str
    value: float
    value_label: str
    y: float
    height: float
    width: float
    """From the plot's left edge."""
    spread: tuple[float, float] | None
    """A whisker's left and right ends (pixels), e.g. the mean less and plus one deviation."""

    @property
    def middle(self) -> float:
        return self.y + self.height / 2


@dataclass(frozen=True)
class BarChart:
    title: str
    axis: str
    """What the values are, with their unit."""
    category: str
    """What each bar is (the vertical axis)."""
    width: int
    height: int
    plot: Box
    bars: list[Bar]
    ticks: list[Tick]


def bar_chart(
    title: str,
    axis: str,
    category: str,
    items: Sequence[tuple[str, float, float | None]],
    *,
    value_label: Callable[[float, float | None], str],
    top: float | None = None,
) -> BarChart:
    """Horizontal bars, one per ``(label, value, spread)``; a spread draws a whisker of ± spread.
    The scale runs from 0 to ``top`` (else to the largest value or whisker, rounded up)."""
    highest = top if top is not None else max((v + (s or 0) for _, v, s in items), default=0.0)
    values = nice_ticks(highest) if top is None else nice_ticks(top)
    scale_top = values[-1]
    plot = Box(LEFT, TOP, WIDTH - LEFT - RIGHT, max(1, len(items)) * BAR_ROW)

    def x(value: float) -> float:
        return plot.width * max(0.0, min(value, scale_top)) / scale_top

    bars = []
    for row, (label, value, spread) in enumerate(items):
        whisker = None
        if spread:
            whisker = (px(plot.left + x(value - spread)), px(plot.left + x(value + spread)))
        bars.append(
            Bar(
                label=label,
                value=value,
                value_label=value_label(value, spread),
                y=plot.top + row * BAR_ROW + 4,
                height=BAR_ROW - 8,
                width=px(x(value)),
                spread=whisker,
            )
        )
    ticks = [Tick(px(plot.left + x(v)), number(v)) for v in values]
    return BarChart(title, axis, category, WIDTH, int(plot.bottom + BOTTOM), plot, bars, ticks)


@dataclass(frozen=True)
class Point:
    x: float
    y: float
    label: str


@dataclass(frozen=True)
class TimeChart:
    title: str
    axis: str
    """What the values are, with their unit (the time axis is UTC)."""
    width: int
    height: int
    plot: Box
    line: str
    """The step line's points, ``x,y x,y …``."""
    points: list[Point]
    x_ticks: list[Tick]
    y_ticks: list[Tick]


def time_chart(
    title: str, axis: str, spans: Sequence[tuple[datetime, datetime, float]], *, height: int = 200
) -> TimeChart:
    """A step line: each ``(start, end, value)`` a level from start to end (a rate over a bucket)."""
    plot = Box(LEFT, TOP, WIDTH - LEFT - RIGHT, height - TOP - BOTTOM)
    values = nice_ticks(max((v for _, _, v in spans), default=0.0), count=4)
    first = min((s for s, _, _ in spans), default=datetime.now(timezone.utc))
    last = max((e for _, e, _ in spans), default=first)
    seconds = max((last - first).total_seconds(), 1.0)

    def x(moment: datetime) -> float:
        return plot.left + plot.width * (moment - first).total_seconds() / seconds

    def y(value: float) -> float:
        return plot.bottom - plot.height * value / values[-1]

    corners = [f"{x(at):.1f},{y(v):.1f}" for start, end, v in spans for at in (start, end)]
    points = [Point(px(x(end)), px(y(v)), f"{end:%H:%M:%S}: {number(round(v, 3))}") for _, end, v in spans]
    y_ticks = [Tick(px(y(v)), number(v)) for v in values]
    return TimeChart(
        title, axis, WIDTH, height, plot, " ".join(corners), points, time_ticks(first, last, x), y_ticks
    )


def time_ticks(first: datetime, last: datetime, x: Callable[[datetime], float], most: int = 6) -> list[Tick]:
    """Ticks on round times (every 10 s … 7 days, the finest that gives at most ``most``); a span
    too short for two of them is marked at its ends."""
    span = last - first
    step = next((s for s in TIME_STEPS if span / s <= most), TIME_STEPS[-1])
    at = EPOCH + math.ceil((first - EPOCH) / step) * step
    shape = "%H:%M:%S" if step < timedelta(minutes=1) else "%H:%M" if step < timedelta(days=1) else "%m-%d"
    moments = []
    while at <= last:
        moments.append(at)
        at += step
    if len(moments) < 2:
        moments, shape = ([first, last] if last > first else [first]), "%H:%M:%S"
    return [Tick(px(x(moment)), moment.strftime(shape)) for moment in moments]
