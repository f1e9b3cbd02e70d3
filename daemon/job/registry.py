"""The units of work under the chart's leaf names, checked against ``statechart.chart`` on import.

``STATES`` lists the job's top-level states with their stages, in the chart's order; ``UNITS`` maps each
leaf to its unit, which is all the runner dispatches on. Importing this module fails (``ChartMismatch``)
when a job leaf of the chart has no unit, a unit has no leaf, the stages are listed out of the chart's
order, a unit may end with an event the chart does not take from its leaf, or it declares a context key
``JobContext`` does not have.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Final

from daemon.job.context import KEYS
from daemon.job.detect import Detect
from daemon.job.errors import ChartMismatch
from daemon.job.manipulation import FLIP, PLACE, SIDE_GRASP
from daemon.job.plan import Plan
from daemon.job.recover import RecoverLostMug
from daemon.job.unit import Stages, Unit
from statechart.chart import JOB_STATES, triggers_from
from statechart.chart import STATES as CHART_STATES


def check_against_chart(states: Sequence[Stages]) -> dict[str, Unit]:
    """The units by leaf when ``states`` matches the chart's job states one to one, else ``ChartMismatch``
    naming every difference."""
    problems: list[str] = []
    chart = {s.name: s for s in CHART_STATES if s.name in JOB_STATES}
    names = [s.state for s in states]
    missing = [n for n in JOB_STATES if n not in names]
    extra = [n for n in names if n not in chart]
    if missing:
        problems.append(f"no units for the states {', '.join(missing)}")
    if extra:
        problems.append(f"units for states the chart does not have: {', '.join(extra)}")
    units: dict[str, Unit] = {}
    for state in states:
        spec = chart.get(state.state)
        if spec is not None:
            problems += _stage_problems(state, spec.leaves)
        for unit in state.stages:
            problems += _unit_problems(unit)
            units[unit.leaf] = unit
    if problems:
        raise ChartMismatch(f"the job's units do not match statechart.chart: {'; '.join(problems)}")
    return units


def _stage_problems(state: Stages, chart_leaves: tuple[str, ...]) -> list[str]:
    leaves = tuple(u.leaf for u in state.stages)
    missing = [leaf for leaf in chart_leaves if leaf not in leaves]
    extra = [leaf for leaf in leaves if leaf not in chart_leaves]
    problems = []
    if missing:
        problems.append(f"no unit for the leaves {', '.join(missing)}")
    if extra:
        problems.append(f"units for leaves the chart does not have: {', '.join(extra)}")
    if not missing and not extra and leaves != chart_leaves:
        problems.append(
            f"{state.state} lists {', '.join(leaves)}; the chart's order is {', '.join(chart_leaves)}"
        )
    return problems


def _unit_problems(unit: Unit) -> list[str]:
    problems = []
    taken = triggers_from(unit.leaf)
    untaken = [t for t in unit.outcomes if t not in taken]
    if untaken:
        problems.append(f"{unit.leaf} may end with {', '.join(untaken)}, which the chart does not take there")
    unknown = sorted((unit.reads | unit.writes) - KEYS)
    if unknown:
        problems.append(f"{unit.leaf} declares context keys JobContext does not have: {', '.join(unknown)}")
    return problems


STATES: Final = (
    Stages("detect", (Detect(),)),
    Stages("plan", (Plan(),)),
    SIDE_GRASP,
    FLIP,
    PLACE,
    Stages("recover_lost_mug", (RecoverLostMug(),)),
)
UNITS: Final[Mapping[str, Unit]] = check_against_chart(STATES)
