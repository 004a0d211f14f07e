"""Evaluation: per behaviour, successes, failures, success rate and the mean and deviation of the
duration (computed by the database, as ``fleetbus evaluate`` and ``GET /recording/evaluation``),
and the recording's growth and insert rate (as ``GET /recording/growth``), charted as SVG."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta, timezone
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import HTMLResponse, Response
from pydantic import BaseModel

from fleetbus.api.auth import ServiceDep
from fleetbus.api.console.charts import BarChart, TimeChart, bar_chart, time_chart
from fleetbus.api.console.forms import FormProblem, moment, robot_name
from fleetbus.api.console.session import Allowed
from fleetbus.api.console.sitemap import EVALUATION
from fleetbus.api.console.templating import render
from fleetbus.api.services.accounts import User
from fleetbus.api.services.recording import OutcomeStats
from fleetbus.workers.recorder.growth import LONGEST_BUCKET, SHORTEST_BUCKET, Growth

router = APIRouter()
Viewer = Annotated[User, Depends(Allowed.page(EVALUATION))]
#: The growth charts' window and bucket when the form gives none (as ``GET /recording/growth``).
GROWTH_WINDOW = timedelta(hours=1)
DEFAULT_EVERY_MINUTES = 1.0
FEWEST_EVERY_MINUTES = SHORTEST_BUCKET / timedelta(minutes=1)
MOST_EVERY_MINUTES = LONGEST_BUCKET / timedelta(minutes=1)


def every_of(text: str) -> float:
    if not text.strip():
        return DEFAULT_EVERY_MINUTES
    try:
        minutes = float(text)
    except ValueError:
        raise FormProblem(f"bucket: {text!r} is not a number of minutes") from None
    if not FEWEST_EVERY_MINUTES <= minutes <= MOST_EVERY_MINUTES:
        raise FormProblem(
            f"bucket: from {FEWEST_EVERY_MINUTES:.4g} ({SHORTEST_BUCKET.total_seconds():g} s) "
            f"to {MOST_EVERY_MINUTES:g} minutes"
        )
    return minutes


def outcome_charts(stats: Sequence[OutcomeStats]) -> tuple[BarChart, BarChart]:
    rates = bar_chart(
        "Success rate per behaviour",
        "success rate (%)",
        "behaviour",
        [(s.name, 100 * s.success_rate, None) for s in stats],
        value_label=lambda value, _: f"{value:.1f} %",
        top=100,
    )
    durations = bar_chart(
        "Duration per behaviour",
        "duration (s): mean, whisker ± one standard deviation",
        "behaviour",
        [(s.name, s.mean_duration, s.std_duration) for s in stats],
        value_label=lambda value, spread: f"{value:.3f} s ± {spread or 0:.3f} s",
    )
    return rates, durations


def growth_charts(rows: Sequence[Growth]) -> tuple[TimeChart, TimeChart]:
    grown = [(r.start, r.end, r.megabytes_per_minute) for r in rows]
    inserts = [(r.start, r.end, r.inserts_per_minute) for r in rows]
    return (
        time_chart("Recording growth", "growth (MB per minute)", grown),
        time_chart("Insert rate", "inserts per minute", inserts),
    )


class EvaluationForm(BaseModel):
    """The evaluation's window and robot, and the growth charts' start and bucket, as typed."""

    since: str = ""
    until: str = ""
    robot: str = ""
    growth_since: str = ""
    every: str = ""


@router.get("/console/evaluation", response_class=HTMLResponse)
async def evaluation(
    request: Request, user: Viewer, svc: ServiceDep, form: Annotated[EvaluationForm, Query()]
) -> Response:
    problem = None
    stats: list[OutcomeStats] = []
    rows: list[Growth] = []
    start = datetime.now(timezone.utc) - GROWTH_WINDOW
    try:
        window = moment("since", form.since), moment("until", form.until)
        robot_id = robot_name(form.robot)
        start = moment("growth since", form.growth_since) or start
        minutes = every_of(form.every)
    except FormProblem as error:
        problem = str(error)
    else:
        stats = await svc.recording_queries.evaluate(*window, robot_id=robot_id)
        rows = await svc.recording_queries.growth(start, timedelta(minutes=minutes))
    rates, durations = outcome_charts(stats)
    grown, inserts = growth_charts(rows)
    return render(
        request,
        "evaluation/page.html",
        user,
        EVALUATION,
        status_code=422 if problem else 200,
        problem=problem,
        form=form,
        stats=stats,
        rows=rows,
        start=start,
        rates=rates,
        durations=durations,
        grown=grown,
        inserts=inserts,
    )
