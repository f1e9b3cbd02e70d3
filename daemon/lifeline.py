"""Helper processes die with the daemon: the planning worker and the multiprocessing forkserver it comes from.

A ``kill -9`` of the daemon runs none of its cleanup, and the helpers do not notice on their own: the worker
waits on its call queue, whose write end it holds itself; the forkserver waits for every holder of its
"alive" pipe, the worker among them; the resource tracker waits for both. So the helpers watch the daemon:

- the forkserver asks the kernel for SIGKILL when its parent, the daemon, dies (``PR_SET_PDEATHSIG``, set
  by ``daemon.forkserver_preload`` as it starts; the daemon starts it from its main thread, since the
  signal follows the thread that forked);
- the worker asks for SIGKILL when the forkserver dies, and also watches the daemon itself through a pidfd
  (its exit is seen at once, however the forkserver fares);
- the resource tracker then sees the last holder of its pipe go, cleans up and exits by itself.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import sys
import threading

_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int | None = None) -> None:
    """SIGKILL this process when its parent dies; exit at once when it is gone already (or, given
    ``parent_pid``, when the parent is not that process any more). Linux only; elsewhere nothing."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
        return
    if os.getppid() == 1 or (parent_pid is not None and os.getppid() != parent_pid):
        os._exit(1)  # the parent died before the request was in place


def exit_with(pid: int) -> None:
    """Exit this process as soon as process ``pid`` has ended (a thread waits on its pidfd)."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        os._exit(1)
    except (AttributeError, OSError):  # no pidfd on this kernel or platform: the death signal must do
        return

    def watch() -> None:
        select.select([fd], [], [])
        os._exit(1)

    threading.Thread(target=watch, name=f"exit-with-{pid}", daemon=True).start()
