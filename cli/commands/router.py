"""``dishbot router``: a Zenoh router (zenoh-python in router mode) for fleets and robots behind NAT.

Robots connect to it (``[zenoh] connect``), and so do operators and monitors; it forwards between them. It
takes the same ``[zenoh]`` section as the daemon (TLS, user/password, roles: on a router, ``robots`` lists
the robots allowed to serve their own ``dishbot/<id>/**``), and refuses plain endpoints beyond loopback in
the same way. Under systemd (``systemd/dishbot-router.service``) it says READY once it listens and pings
the watchdog.
"""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path
from types import FrameType


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "router",
        help="run a Zenoh router for a fleet, with the same TLS, passwords and roles as the daemon",
        description=(
            "Run a Zenoh router: robots and clients connect to it and it forwards between them (a fleet, or "
            "robots behind NAT). It reads the [zenoh] section of --config: listen and connect endpoints, "
            "[zenoh.tls], [zenoh.auth] and [zenoh.access] (operators, monitors, and the robots allowed to "
            "serve their own keys). SIGTERM or Ctrl-C stops it."
        ),
    )
    parser.add_argument("--config", type=Path, metavar="FILE", help="TOML file with a [zenoh] section")
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tls/10.0.0.5:3474 (repeatable; default: config)",
    )
    parser.add_argument(
        "--connect", action="append", metavar="ENDPOINT", help="another router to connect to (repeatable)"
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow plain endpoints other machines can reach (anyone who reaches them can command robots)",
    )
    parser.set_defaults(handler=_router)


def _router(args: argparse.Namespace) -> int:
    import structlog
    import zenoh

    from daemon.config import load_config
    from daemon.errors import ConfigError, UsageError
    from daemon.sdnotify import SdNotifier
    from daemon.security import check_endpoint, exposure_error, node_settings
    from daemon.zenoh_session import error_text, session_config

    log = structlog.get_logger("daemon.router")
    zenoh_config = load_config(args.config).zenoh
    try:
        listen = tuple(check_endpoint(e, "--listen") for e in args.listen or ()) or zenoh_config.listen
        connect = tuple(check_endpoint(e, "--connect") for e in args.connect or ()) or zenoh_config.connect
    except ConfigError as e:
        raise UsageError(str(e)) from e
    if not listen:
        raise UsageError("the router listens nowhere: give --listen or [zenoh] listen")
    exposed = exposure_error(listen, connect, zenoh_config)
    if exposed is not None:
        if not (args.insecure or zenoh_config.insecure):
            raise UsageError(exposed)
        log.warning("zenoh_insecure", problem=exposed)
    settings = node_settings(zenoh_config)
    config = session_config(listen=listen, connect=connect, mode="router", settings=settings)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with SdNotifier.from_env() as notifier:
            try:
                session = zenoh.open(config)
            except zenoh.ZError as e:
                raise UsageError(f"cannot open the router (listen {list(listen)}): {error_text(e)}") from e
            with session:

                def on_event(
                    event: zenoh.TransportEvent,
                ) -> None:  # on a Zenoh thread; logging does not block
                    transport = event.transport
                    opened = event.kind == zenoh.SampleKind.PUT
                    client = transport.whatami == zenoh.WhatAmI.CLIENT
                    (log.debug if client else log.info)(
                        "router_link_opened" if opened else "router_link_closed",
                        remote=str(transport.whatami),
                        zid=str(transport.zid),
                    )

                listener = session.info.declare_transport_events_listener(on_event, history=False)
                notifier.ready(f"routing on {', '.join(listen)}")
                log.info(
                    "router_ready", listen=list(listen), connect=list(connect), zid=str(session.info.zid())
                )
                interval = (notifier.watchdog_interval_s or 2.0) / 2.0
                while not stop.wait(interval):
                    notifier.watchdog()
                notifier.stopping("closing the router")
                listener.undeclare()  # type: ignore[no-untyped-call]
            log.info("router_stopped")
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
