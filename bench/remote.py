"""``dishbot bench remote``: commanding a robot from another host over TLS, next to plain TCP on loopback.

Two network namespaces joined by a veth pair stand for the robot's computer and the operator's; their
addresses (10.200.0.1 and 10.200.0.2) exist only inside them and nothing is routed elsewhere. The robot's
daemon (kinematic cell) runs in one with the files ``dishbot security init`` writes; a ``dishbot router`` and
an operator agent run in the other. Measured: the ``status`` round trip over mutual TLS across the link,
directly and through the router; the same against a plain daemon on loopback TCP in this process's own
namespace, in the same run; how long after the link comes back (from a 10 s cut), and after a restarted
router listens again, a new command is answered and a watching session receives the robot's state again.

The namespace plumbing and the operator agent here are also what the two-host tests use. Needs root (to
create namespaces); where the kernel refuses, the benchmark says so and exits 1.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.security import DEFAULT_PORT

ROBOT_ADDRESS = "10.200.0.1"  # only inside the robot's namespace
OPERATOR_ADDRESS = "10.200.0.2"  # only inside the operator's namespace
PORT = DEFAULT_PORT
ROBOT = "r1"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "remote",
        help="command round trip over TLS across two network namespaces vs loopback TCP; resume times",
        description=(
            "Create two network namespaces joined by a veth pair (10.200.0.1, 10.200.0.2: they exist only "
            "inside them), run the daemon (kinematic cell) with mutual TLS, passwords and roles in one and a "
            "router and an operator in the other, and measure the status round trip across the link (direct "
            "and through the router) next to a plain daemon on loopback TCP, then the time to resume after a "
            "link cut and after a router restart. Needs root."
        ),
    )
    parser.add_argument(
        "--commands", type=int, default=300, metavar="N", help="round trips each (default 300)"
    )
    parser.add_argument(
        "--cut", type=float, default=10.0, metavar="S", help="how long the link is down (default 10 s)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the table")
    parser.set_defaults(handler=_bench)


# --- namespaces ---------------------------------------------------------------------------------------------


def netns_refused() -> str | None:
    """Why network namespaces cannot be made here, or None when they can."""
    probe = f"dbprobe{os.getpid()}"
    try:
        made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"cannot run ip netns: {e}"
    if made.returncode != 0:
        return f"the kernel refuses network namespaces here: {made.stderr.strip() or made.returncode}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=10, check=False)
    return None


class Proc:
    """A process (usually in a namespace) whose output lines are collected as they come."""

    def __init__(self, name: str, argv: Sequence[str], env: Mapping[str, str]) -> None:
        self.name = name
        self.lines: list[str] = []
        self.times: list[float] = []  # when each line was read (wall clock)
        self._eof = False
        self._cond = threading.Condition()
        self.popen = subprocess.Popen(
            list(argv), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dict(env)
        )
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self.times.append(time.time())
                self._cond.notify_all()
        with self._cond:
            self._eof = True
            self._cond.notify_all()

    def wait_for(self, text: str, *, timeout_s: float = 60.0, after: int = 0) -> int:
        """The index of the first output line from ``after`` on that contains ``text``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for i in range(after, len(self.lines)):
                    if text in self.lines[i]:
                        return i
                left = deadline - time.monotonic()
                if left <= 0 or self._eof:
                    tail = "\n".join(self.lines[-15:])
                    raise RuntimeError(
                        f"{self.name}: no line with {text!r} (exit {self.popen.poll()}):\n{tail}"
                    )
                self._cond.wait(min(left, 0.2))

    def stop(self, *, timeout_s: float = 30.0) -> int:
        """SIGTERM, then SIGKILL if it does not exit in time; the exit code."""
        return stop(self.popen, timeout_s=timeout_s)


def stop(popen: subprocess.Popen[str], *, timeout_s: float = 30.0) -> int:
    """SIGTERM ``popen``, then SIGKILL if it does not exit in time; its exit code."""
    if popen.poll() is None:
        popen.send_signal(signal.SIGTERM)
        try:
            popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait(10)
    return popen.returncode


@dataclass
class NamespacePair:
    """The robot's namespace and the operator's, a veth pair between them, and the processes started."""

    robot: str
    operator: str
    robot_link: str
    operator_link: str
    started: list[subprocess.Popen[str]] = field(default_factory=list)  # stopped at the end, newest first

    def command(self, side: str, argv: Sequence[str]) -> list[str]:
        return ["ip", "netns", "exec", self._ns(side), *argv]

    def start(self, side: str, name: str, argv: Sequence[str]) -> Proc:
        """Start ``argv`` in ``side`` ("robot" or "operator"; "host" for this process's namespace)."""
        command = list(argv) if side == "host" else self.command(side, argv)
        proc = Proc(name, command, python_env())
        self.started.append(proc.popen)
        return proc

    def dishbot(self, side: str, name: str, *args: str) -> Proc:
        return self.start(side, name, [sys.executable, "-m", "cli.main", *args])

    def cut(self) -> None:
        """Take the robot's end of the link down: nothing passes until ``restore``."""
        _ip("-n", self.robot, "link", "set", self.robot_link, "down")

    def restore(self) -> None:
        _ip("-n", self.robot, "link", "set", self.robot_link, "up")

    def _ns(self, side: str) -> str:
        return {"robot": self.robot, "operator": self.operator}[side]


@contextlib.contextmanager
def namespace_pair(tag: str = "r") -> Iterator[NamespacePair]:
    """Two fresh namespaces joined by a veth pair (10.200.0.1/30 and .2/30); everything started in them is
    stopped and both are deleted at the end."""
    suffix = f"{tag}{os.getpid()}"
    pair = NamespacePair(
        f"dishbot-robot-{suffix}", f"dishbot-op-{suffix}", f"dbr{suffix}"[:15], f"dbo{suffix}"[:15]
    )
    made: list[str] = []
    try:
        for ns in (pair.robot, pair.operator):
            _ip("netns", "add", ns)
            made.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        _ip("link", "add", pair.robot_link, "type", "veth", "peer", "name", pair.operator_link)
        for ns, link, address in (
            (pair.robot, pair.robot_link, ROBOT_ADDRESS),
            (pair.operator, pair.operator_link, OPERATOR_ADDRESS),
        ):
            _ip("link", "set", link, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{address}/30", "dev", link)
            _ip("-n", ns, "link", "set", link, "up")
        yield pair
    finally:
        for popen in reversed(pair.started):
            stop(popen, timeout_s=20)
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30, check=False)
        # A veth not yet moved into a namespace would be left in ours.
        subprocess.run(["ip", "link", "del", pair.robot_link], capture_output=True, timeout=30, check=False)


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")


def python_env() -> dict[str, str]:
    """This process's environment with our packages importable by a child Python."""
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("MUJOCO_GL", "egl")
    env["PYTHONUNBUFFERED"] = "1"
    return env


# --- the operator agent: one long-lived Python in a namespace, doing what it is asked -----------------------


class Agent:
    """Talks JSON lines to ``python -m bench.remote`` running in a namespace (see ``agent_main``)."""

    def __init__(self, pair: NamespacePair, side: str) -> None:
        argv = pair.command(side, [sys.executable, "-m", "bench.remote"])
        self.popen = subprocess.Popen(
            argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=python_env(), bufsize=1
        )
        pair.started.append(self.popen)

    def call(self, op: str, **params: Any) -> dict[str, Any]:
        assert self.popen.stdin is not None
        assert self.popen.stdout is not None
        self.popen.stdin.write(json.dumps({"op": op, **params}) + "\n")
        self.popen.stdin.flush()
        line = self.popen.stdout.readline()
        if not line:
            raise RuntimeError(f"the agent exited ({self.popen.poll()}) during {op}")
        answer: dict[str, Any] = json.loads(line)
        if "crash" in answer:
            raise RuntimeError(f"the agent failed {op}: {answer['crash']}")
        return answer

    def cli(self, *argv: str) -> tuple[int, str, str]:
        """``dishbot ARGV`` run by the agent: exit code, stdout, stderr (log lines left out)."""
        answer = self.call("cli", argv=list(argv))
        return answer["code"], answer["out"], answer["err"]


def agent_main() -> None:
    """Answer one JSON request per stdin line with one JSON line on stdout, until stdin closes."""
    state = _AgentState()
    out = sys.stdout
    try:
        for line in sys.stdin:
            request = json.loads(line)
            try:
                answer = state.do(request)
            except Exception as e:  # reported to the test or benchmark, which fails with it
                answer = {"crash": f"{type(e).__name__}: {e}"}
            out.write(json.dumps(answer) + "\n")
            out.flush()
    finally:
        state.close()


class _AgentState:
    """The agent's long-lived watching sessions and when each heard the robot's state."""

    def __init__(self) -> None:
        self.sessions: dict[str, Any] = {}
        self.heard: dict[str, list[float]] = {}

    def close(self) -> None:
        for session in self.sessions.values():
            session.close()

    def do(self, request: dict[str, Any]) -> dict[str, Any]:
        from cli.commands.client import Target, Unreachable, ask, client_session
        from cli.main import main
        from daemon.security import load_profile
        from daemon.zenoh_session import session_config
        from wire.messages import reply_of

        op = request["op"]
        if op == "cli":
            out, err = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = main(request["argv"])
            return {"code": code, "out": _no_logs(out.getvalue()), "err": _no_logs(err.getvalue())}
        profile = load_profile(Path(request["profile"])) if request.get("profile") else None
        endpoint = request.get("connect") or (profile.endpoint if profile else "")
        t = Target(endpoint, request.get("robot", ROBOT), profile)
        if op == "rtt":  # status round trips on one session
            with client_session(t) as session:
                ask(session, t, "status", {}, timeout_s=5.0)  # warm: routes and keys declared
                ms = []
                for _ in range(int(request["n"])):
                    t0 = time.perf_counter()
                    if not ask(session, t, "status", {}, timeout_s=5.0):
                        raise RuntimeError(f"no reply from {t.robot} at {t.endpoint}")
                    ms.append((time.perf_counter() - t0) * 1000.0)
            return {"ms": ms}
        if op == "until_answered":  # a new command (new session each time), retried until answered
            deadline = time.monotonic() + float(request.get("timeout_s", 60.0))
            tries = 0
            while time.monotonic() < deadline:
                tries += 1
                try:
                    with client_session(t) as session:
                        replies = ask(session, t, "status", {}, timeout_s=1.0)
                    if replies and reply_of(replies[0]).ok is True:
                        return {"t": time.time(), "tries": tries, "reply": replies[0]}
                except Unreachable:
                    pass
                time.sleep(0.1)
            raise RuntimeError(f"no answer from {t.robot} at {t.endpoint} after {tries} tries")
        if op == "watch":  # a long-lived session following the robot's state, as a monitor does
            import zenoh

            heard: list[float] = []
            config = session_config(listen=[], connect=[t.endpoint], mode="client", settings=t.settings())
            session = zenoh.open(config)
            session.declare_subscriber(f"dishbot/{t.robot}/state", lambda sample: heard.append(time.time()))
            self.sessions[request["name"]], self.heard[request["name"]] = session, heard
            return {}
        if op == "first_state_after":  # when the watcher first heard the robot after time t
            heard = self.heard[request["name"]]
            deadline = time.monotonic() + float(request.get("timeout_s", 60.0))
            while time.monotonic() < deadline:
                later = [s for s in list(heard) if s > request["t"]]
                if later:
                    return {"t": later[0]}
                time.sleep(0.02)
            raise RuntimeError(f"the watcher {request['name']} heard nothing after t={request['t']}")
        raise RuntimeError(f"unknown op {op!r}")


def _no_logs(text: str) -> str:
    return "".join(line for line in text.splitlines(keepends=True) if not line.startswith("20"))


# --- the benchmark ------------------------------------------------------------------------------------------


def _bench(args: argparse.Namespace) -> int:
    from cli.commands.output import emit
    from daemon.errors import UsageError

    if not 10 <= args.commands <= 100_000:
        raise UsageError(f"--commands {args.commands}: choose 10-100000")
    if not 1.0 <= args.cut <= 120:
        raise UsageError(f"--cut {args.cut:g}: choose 1-120 seconds")
    refused = netns_refused()
    if refused is not None:
        print(f"dishbot bench remote: {refused}", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory(prefix="dishbot-bench-remote-") as tmp:
        result = measure(Path(tmp), commands=args.commands, cut_s=args.cut)
    rows = [
        ["status round trip, mutual TLS across the link", "ms", *_percentiles(result["tls_direct_ms"])],
        ["status round trip, TLS through the router", "ms", *_percentiles(result["tls_router_ms"])],
        ["status round trip, plain TCP on loopback", "ms", *_percentiles(result["tcp_loopback_ms"])],
        [f"new command answered after a {args.cut:g} s link cut", "s", result["resume_command_s"], "", ""],
        [f"watcher hears the robot after a {args.cut:g} s link cut", "s", result["resume_watch_s"], "", ""],
        ["router restart: from launch to listening", "s", result["router_start_s"], "", ""],
        ["router restart: then a new command is answered", "s", result["router_command_s"], "", ""],
        ["router restart: then the watcher hears the robot", "s", result["router_watch_s"], "", ""],
    ]
    emit(
        "dishbot bench remote",
        ["measure", "unit", "p50", "p99", "max"],
        rows,
        as_json=args.json,
        extra={"commands": args.commands, "cut_s": args.cut, "load_average_1m": round(os.getloadavg()[0], 2)},
    )
    return 0


def measure(tmp: Path, *, commands: int, cut_s: float) -> dict[str, Any]:
    """Set the two hosts up and take every number of the table."""
    from cli import credentials

    keys = tmp / "keys"
    plan = credentials.plan(
        ROBOT,
        addresses=[ROBOT_ADDRESS],
        operators=["op"],
        monitors=["mon"],
        router=OPERATOR_ADDRESS,
        port=PORT,
    )
    credentials.write(plan, keys)
    profile = str(keys / "op.profile.toml")
    direct = f"tls/{ROBOT_ADDRESS}:{PORT}"
    plain_endpoint = f"tcp/127.0.0.1:{_free_port()}"
    with namespace_pair("b") as pair:
        router = pair.dishbot("operator", "router", "router", "--config", str(keys / "router.toml"))
        router.wait_for("router_ready")
        daemon = pair.dishbot(
            "robot", "daemon", "run", "--sim", "--world", "kinematic", "--config", str(keys / "robot.toml"),
            "--record-dir", str(tmp / "robot"),
        )  # fmt: skip
        plain = pair.dishbot(
            "host", "plain daemon", "run", "--sim", "--world", "kinematic", "--listen", plain_endpoint,
            "--record-dir", str(tmp / "plain"),
        )  # fmt: skip
        daemon.wait_for("daemon_ready")
        plain.wait_for("daemon_ready")
        agent = Agent(pair, "operator")
        agent.call("until_answered", profile=profile)  # through the router: the robot is connected
        tls_direct = agent.call("rtt", profile=profile, connect=direct, n=commands)["ms"]
        tls_router = agent.call("rtt", profile=profile, n=commands)["ms"]
        tcp_loopback = _rtt_here(plain_endpoint, commands)
        agent.call("watch", name="direct", profile=profile, connect=direct)
        agent.call("watch", name="router", profile=profile)

        pair.cut()
        time.sleep(cut_s)
        pair.restore()
        restored = time.time()
        resume_command = agent.call("until_answered", profile=profile, connect=direct)["t"] - restored
        resume_watch = agent.call("first_state_after", name="direct", t=restored)["t"] - restored

        router.stop()
        lost = daemon.wait_for("connection_lost")
        relaunched = time.time()
        router = pair.dishbot("operator", "router again", "router", "--config", str(keys / "router.toml"))
        answered = agent.call("until_answered", profile=profile)["t"]
        heard = agent.call("first_state_after", name="router", t=relaunched)["t"]
        ready = router.times[router.wait_for("router_ready")]
        daemon.wait_for("connection_restored", after=lost)
    return {
        "tls_direct_ms": tls_direct,
        "tls_router_ms": tls_router,
        "tcp_loopback_ms": tcp_loopback,
        "resume_command_s": round(resume_command, 2),
        "resume_watch_s": round(resume_watch, 2),
        "router_start_s": round(ready - relaunched, 2),
        "router_command_s": round(answered - ready, 2),
        "router_watch_s": round(heard - ready, 2),
    }


def _rtt_here(endpoint: str, n: int) -> list[float]:
    from cli.commands.client import Target, ask, client_session

    t = Target(endpoint, "dishbot")
    deadline = time.monotonic() + 60
    while True:
        try:
            with client_session(t) as session:
                if ask(session, t, "status", {}, timeout_s=5.0):
                    ms = []
                    for _ in range(n):
                        t0 = time.perf_counter()
                        ask(session, t, "status", {}, timeout_s=5.0)
                        ms.append((time.perf_counter() - t0) * 1000.0)
                    return ms
        except ConnectionError:
            if time.monotonic() > deadline:
                raise
        time.sleep(0.2)


def _percentiles(values: list[float]) -> list[float]:
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return [round(statistics.median(ordered), 3), round(p99, 3), round(ordered[-1], 3)]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


if __name__ == "__main__":
    agent_main()
