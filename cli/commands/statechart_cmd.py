"""``dishbot statechart``: print the loading job's statechart as a Mermaid diagram."""

from __future__ import annotations

import argparse

from statechart.mermaid import to_mermaid


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "statechart",
        help="print the statechart (states, events, guards) as a Mermaid stateDiagram",
        description="Print the loading job's statechart as Mermaid; paste it into any Mermaid renderer.",
    )
    parser.set_defaults(handler=_print)


def _print(args: argparse.Namespace) -> int:
    print(to_mermaid(), end="")
    return 0
