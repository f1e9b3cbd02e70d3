"""Free TCP ports for tests that hand a port to something that binds it later (a daemon subprocess, a Zenoh
listener, a Foxglove server): never the same port twice in one run, even with pytest-xdist's workers.

Asking the kernel for port 0 and closing the socket again gives a port from the ephemeral range, which any
outgoing connection on the machine may take before the daemon binds it, and which another worker may be
given too. Here each process takes its ports from a block of its own below the ephemeral range (xdist worker
``gwN`` block N, a run without xdist the last block), in turn from a random start, each one checked free
(bound on every address and released) and not handed out again by the process until half a block of
others has been. Two suites of different
checkouts on one machine start at different random points of a block and skip each other's bound ports.
"""

from __future__ import annotations

import collections
import itertools
import os
import random
import socket
import threading
from collections.abc import Iterator

FIRST_PORT = 20_000
BLOCK = 1_000
BLOCKS = 12  # 20000-31999: below Linux's ephemeral range (32768-60999 by default)


def block(worker: str | None) -> range:
    """The ports of ``worker`` (``PYTEST_XDIST_WORKER``: gw0, gw1, ...; None without xdist)."""
    index = BLOCKS - 1
    if worker is not None and worker.removeprefix("gw").isdigit():
        index = int(worker.removeprefix("gw")) % (BLOCKS - 1)
    start = FIRST_PORT + index * BLOCK
    return range(start, start + BLOCK)


def _candidates(ports: range) -> Iterator[int]:
    first = random.SystemRandom().randrange(len(ports))
    for i in itertools.count():
        yield ports[(first + i) % len(ports)]


_lock = threading.Lock()
# The ports handed out lately: none of them again until half a block of others has been (a port given long
# ago is released by then, and a bound one fails ``is_free`` anyway), so a process can ask without end.
_given: collections.deque[int] = collections.deque(maxlen=BLOCK // 2)
_mine = block(os.environ.get("PYTEST_XDIST_WORKER"))
_ours = _candidates(_mine)


def is_free(port: int) -> bool:
    """Nothing has ``port`` bound (nor in TIME_WAIT) on any address now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    """A TCP port that nothing holds right now and that no other test of this run is given."""
    with _lock:
        for _ in range(BLOCK):
            port = next(_ours)
            if port not in _given and is_free(port):
                _given.append(port)
                return port
    raise RuntimeError(f"no free port left in this process's block {_mine}")
