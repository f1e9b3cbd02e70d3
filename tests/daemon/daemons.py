"""In-process daemons, routers and client calls on loopback for the security and fleet tests."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
import zenoh

from cli.commands.client import request
from cli.main import main
from daemon.config import Config, load_config
from daemon.security import Profile, ZenohConfig, node_settings
from daemon.zenoh_session import session_config
from tests.fakes.daemon import Daemon, running_daemon
from tests.fakes.job import make_backend, make_world


@contextlib.asynccontextmanager
async def daemon(
    tmp_path: Path, config: Config, *, listen: Sequence[str], connect: Sequence[str] = (), mugs: int = 2
) -> AsyncIterator[Daemon]:
    """The harness's daemon on the fake cell with ``mugs`` mugs, recording under ``tmp_path/<robot id>``."""
    backend = make_backend(make_world(mugs))
    async with running_daemon(
        config, backend, tmp_path / config.robot_id, listen=listen, connect=connect
    ) as d:
        yield d


def robot_config(robot_id: str, path: Path | None = None, **zenoh: Any) -> Config:
    overrides: dict[str, Any] = {"robot_id": robot_id, "planner": {"method": "bh"}}
    if zenoh:
        overrides["zenoh"] = zenoh
    return load_config(path, overrides=overrides)


@contextlib.contextmanager
def router(listen: str, zenoh_config: ZenohConfig | None = None) -> Iterator[zenoh.Session]:
    """A Zenoh router session, as ``dishbot router`` opens it."""
    settings = node_settings(zenoh_config) if zenoh_config is not None else {}
    with zenoh.open(session_config(listen=[listen], connect=[], mode="router", settings=settings)) as session:
        yield session


async def cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """Run ``dishbot ARGV`` off the loop; its exit code, stdout and stderr (log lines left out)."""
    capsys.readouterr()
    code = await asyncio.to_thread(main, list(argv))
    out, err = capsys.readouterr()
    return code, _without_logs(out), _without_logs(err)


def _without_logs(text: str) -> str:
    return "".join(line for line in text.splitlines(keepends=True) if not line.startswith("20"))


async def until_state(
    endpoint: str, state: str, *, robot: str = "r1", profile: Profile | None = None
) -> None:
    """Wait until the robot reports ``state`` (a job left running would race the daemon's shutdown)."""
    for _ in range(500):
        reply = await asyncio.to_thread(
            request, endpoint, robot, "status", {}, timeout_s=3.0, profile=profile
        )
        if reply is not None and reply.get("state") == state:
            return
        await asyncio.sleep(0.02)
    raise AssertionError(f"robot {robot} never reached {state}")


def ask(
    endpoint: str, key_expr: str, payload: bytes = b"", *, timeout_s: float = 3.0
) -> list[tuple[str, dict[str, Any]]]:
    """(reply key or "error", decoded body) for every reply to one query, from a plain client session."""
    with zenoh.open(session_config(listen=[], connect=[endpoint], mode="client")) as session:
        out = []
        for reply in session.get(key_expr, payload=payload, timeout=timeout_s, target=zenoh.QueryTarget.ALL):
            if reply.ok is not None:
                out.append((str(reply.ok.key_expr), json.loads(reply.ok.payload.to_bytes())))
            elif reply.err is not None:
                try:
                    out.append(("error", json.loads(reply.err.payload.to_bytes())))
                except ValueError:
                    out.append(("error", {"zenoh": reply.err.payload.to_string()}))
        return out
