"""Draw the chart of ``statechart.chart`` as a Mermaid ``stateDiagram-v2`` (``dishbot statechart``).

The job states are drawn inside one box so that the events valid in every one of them (pause, stop, fault,
estop) are drawn once, from the box, instead of once per state.
"""

from __future__ import annotations

from statechart.chart import HISTORY, JOB_STATES, SEPARATOR, STATES, TRANSITIONS, TransitionSpec

_JOB_BOX = "job"


def to_mermaid() -> str:
    """The whole chart: states, substates, every transition with its event and guard."""
    lines = ["stateDiagram-v2", "    [*] --> idle"]
    lines.append(f'    state "loading job" as {_JOB_BOX} {{')
    for spec in STATES:
        if spec.name not in JOB_STATES:
            continue
        if spec.children:
            lines.append(f"        state {spec.name} {{")
            for child in spec.children:
                lines.append(f'            state "{child}" as {_node(spec.name + SEPARATOR + child)}')
            lines.append(f"            [*] --> {_node(spec.leaves[0])}")
            lines.append("        }")
        else:
            lines.append(f"        {spec.name}")
    lines.append("    }")
    for row in TRANSITIONS:
        for source, dest in _edges(row):
            lines.append(f"    {_node(source)} --> {_node(dest)}: {_label(row)}")
    return "\n".join(lines) + "\n"


def _edges(spec: TransitionSpec) -> list[tuple[str, str]]:
    sources = list(spec.sources)
    if set(JOB_STATES) <= set(sources):
        sources = [_JOB_BOX] + [s for s in sources if s not in JOB_STATES]
    dest = _JOB_BOX if spec.dest == HISTORY else spec.dest
    return [(s, dest) for s in sources]


def _label(spec: TransitionSpec) -> str:
    if spec.dest == HISTORY:
        return f"{spec.trigger} (back where it stopped)"
    if spec.guard:
        return f"{spec.trigger} [{spec.guard}]"
    if spec.unless:
        return f"{spec.trigger} [not {spec.unless}]"
    if _is_fallback(spec):
        return f"{spec.trigger} [otherwise]"
    return spec.trigger


def _is_fallback(spec: TransitionSpec) -> bool:
    """An unguarded row after guarded rows of the same trigger and source is taken when none of them is."""
    earlier = TRANSITIONS[: TRANSITIONS.index(spec)]
    return any(
        t.trigger == spec.trigger and set(t.sources) & set(spec.sources) and (t.guard or t.unless)
        for t in earlier
    )


def _node(path: str) -> str:
    return path.replace(SEPARATOR, "_")
