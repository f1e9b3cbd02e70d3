"""The loading job: a small runner (``Job``) and one unit of work per leaf of the chart.

``registry.STATES`` lists the units by top-level state (``detect``, ``plan``, the stages of ``side_grasp``,
``flip`` and ``place``, ``recover_lost_mug``); importing the package checks them against
``statechart.chart``. The units share one ``JobContext`` and reach the devices and planners through
``Services``. docs/daemon.md describes them.
"""

from daemon.job.context import JobContext, JobSummary, Outcome
from daemon.job.errors import ChartMismatch, CommandRefused, UndeclaredKey
from daemon.job.registry import STATES, UNITS
from daemon.job.requests import PlannerRequest, StartRequest
from daemon.job.runner import Job
from daemon.job.services import Services
from daemon.job.unit import Stages, Unit

__all__ = [
    "STATES",
    "UNITS",
    "ChartMismatch",
    "CommandRefused",
    "Job",
    "JobContext",
    "JobSummary",
    "Outcome",
    "PlannerRequest",
    "Services",
    "Stages",
    "StartRequest",
    "UndeclaredKey",
    "Unit",
]
