"""``dishbot config show``: print the effective configuration (defaults plus ``--config`` overrides)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from daemon.config import load_config, to_toml


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("config", help="show the effective configuration")
    config_sub = parser.add_subparsers(dest="config_command", metavar="ACTION", required=True)
    show = config_sub.add_parser(
        "show",
        help="print the effective config as TOML (embedded defaults, then --config overrides), validated",
    )
    show.add_argument("--config", type=Path, metavar="FILE", help="TOML file overriding any subset of keys")
    show.add_argument("--json", action="store_true", help="print JSON instead of TOML")
    show.set_defaults(handler=_show)


def _show(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    if args.json:
        print(json.dumps(config.to_dict(), indent=2))
    else:
        print(to_toml(config.to_dict()), end="")
    return 0
