"""systemd as PID 1 in a throwaway container of its own, for tests of the service unit under real systemd.

The container's root is an overlay of the host's root with a tmpfs upper layer, so nothing it writes reaches
the host; it has fresh /proc, /sys (read-only), /dev, /run and /tmp, its own PID, mount, UTS, IPC, network and
cgroup namespaces, a cgroup2 subtree of its own, and no capability to load modules, set the clock or write
kernel settings (/proc/sys is read-only). Never boot systemd on the shared root: its boot-time
``systemd-tmpfiles`` empties the host's /tmp. The setup script refuses to start systemd unless the root it is
about to use is an overlay and its /tmp and /run are tmpfs, and ``booted`` checks a marker file in the host's
/tmp after the boot.

Mounts vanish with the mount namespace when its last process dies; the processes die with the PID namespace
when systemd (its PID 1) does, which ``unshare --kill-child`` and a parent-death signal ensure even when the
test process is killed. Teardown asks ``systemctl poweroff``, then kills what is left (``cgroup.kill``) and
removes the cgroup tree and the host-side temporary directory.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

SYSTEMD: Final = Path("/lib/systemd/systemd")
TOOLS: Final = ("unshare", "nsenter", "setpriv", "chroot", "mount", "ip")
BOOT_TIMEOUT_S: Final = 30.0
POWEROFF_TIMEOUT_S: Final = 15.0

# Units that touch the kernel, the clock, devices or the console, or that a test does not need; symlinked to
# /dev/null in the container (on top of what systemd skips in a container by itself).
MASKED: Final = (
    "systemd-timesyncd.service",
    "systemd-pstore.service",
    "systemd-modules-load.service",
    "kmod-static-nodes.service",
    "systemd-binfmt.service",
    "proc-sys-fs-binfmt_misc.automount",
    "systemd-sysctl.service",
    "sys-kernel-debug.mount",
    "sys-kernel-tracing.mount",
    "sys-kernel-config.mount",
    "sys-fs-fuse-connections.mount",
    "dev-hugepages.mount",
    "systemd-journald-audit.socket",
    "systemd-udevd.service",
    "systemd-udev-trigger.service",
    "systemd-udev-settle.service",
    "systemd-udevd-control.socket",
    "systemd-udevd-kernel.socket",
    "systemd-hwdb-update.service",
    "systemd-repart.service",
    "systemd-firstboot.service",
    "systemd-remount-fs.service",
    "systemd-ask-password-console.path",
    "systemd-pcrphase.service",
    "systemd-pcrphase-sysinit.service",
    "systemd-networkd-wait-online.service",
    "NetworkManager-wait-online.service",
    "systemd-tmpfiles-clean.timer",
    "apt-daily.timer",
    "apt-daily-upgrade.timer",
    "dpkg-db-backup.timer",
    "e2scrub_all.timer",
    "fstrim.timer",
    "man-db.timer",
)

# Capabilities systemd in the container must not have: they reach the host's kernel, clock or audit log.
DROPPED_CAPABILITIES: Final = (
    "sys_module",
    "sys_time",
    "sys_rawio",
    "wake_alarm",
    "syslog",
    "audit_control",
    "audit_read",
    "audit_write",
    "mac_admin",
    "mac_override",
    "block_suspend",
    "sys_pacct",
)

# Runs as PID 1 of the new PID namespace, in the new (private) mount namespace; $1 is the host-side
# directory, $2 the bounding set to drop. The last line execs systemd, which stays PID 1.
_SETUP: Final = r"""
set -eu
B=$1
BOUNDING=$2
shift 2
mount -t tmpfs -o mode=0755,size=2g tmpfs "$B/fs"
mkdir "$B/fs/upper" "$B/fs/work" "$B/fs/root"
R="$B/fs/root"
mount -t overlay overlay -o "lowerdir=/,upperdir=$B/fs/upper,workdir=$B/fs/work" "$R"
mount -t proc -o nosuid,nodev,noexec proc "$R/proc"
for p in sys sysrq-trigger; do
    if [ -e "$R/proc/$p" ]; then
        mount --bind "$R/proc/$p" "$R/proc/$p"
        mount -o remount,bind,ro "$R/proc/$p"
    fi
done
mount -t sysfs -o ro,nosuid,nodev,noexec sysfs "$R/sys"
mount -t cgroup2 -o nosuid,nodev,noexec cgroup2 "$R/sys/fs/cgroup"
mount -t tmpfs -o mode=0755,nosuid,size=64m tmpfs "$R/dev"
for n in null zero full random urandom tty; do touch "$R/dev/$n"; mount --bind "/dev/$n" "$R/dev/$n"; done
mkdir "$R/dev/pts" "$R/dev/shm"
mount -t devpts -o newinstance,ptmxmode=0666,mode=0620 devpts "$R/dev/pts"
ln -s pts/ptmx "$R/dev/ptmx"
ln -s /proc/self/fd "$R/dev/fd"
ln -s /proc/self/fd/0 "$R/dev/stdin"
ln -s /proc/self/fd/1 "$R/dev/stdout"
ln -s /proc/self/fd/2 "$R/dev/stderr"
mount -t tmpfs -o mode=1777,nosuid,nodev tmpfs "$R/dev/shm"
mount -t tmpfs -o mode=0755,nosuid,nodev,size=64m tmpfs "$R/run"
mount -t tmpfs -o mode=1777,nosuid,nodev,size=256m tmpfs "$R/tmp"
# The checkout and its Python when they live under the host's /tmp or /run (a CI checkout may): the same
# paths inside, read-only, over the fresh tmpfs.
for d in "$@"; do
    mkdir -p "$R$d"
    mount --bind "$d" "$R$d"
    mount -o remount,bind,ro "$R$d"
done
cp -a "$B/seed/." "$R/"
ip link set lo up
[ "$(stat -f -c %T "$R")" = overlayfs ] || { echo "refusing to boot: $R is not an overlay" >&2; exit 97; }
for d in tmp run; do
    [ "$(stat -f -c %T "$R/$d")" = tmpfs ] || { echo "refusing to boot: $R/$d is not a tmpfs" >&2; exit 97; }
done
echo "READY_TO_BOOT"
exec env -i container=dishbot-test PATH=/usr/sbin:/usr/bin:/sbin:/bin \
    setpriv --bounding-set "$BOUNDING" chroot "$R" /lib/systemd/systemd --unit=basic.target
"""


_PREFIX: Final = "dishbot-systemd-"  # then the test process's PID: leftovers of a dead one can go


class Refused(RuntimeError):
    """This machine cannot run the container (not root, a tool missing, or the kernel refused a namespace,
    a mount or a cgroup); the message says which, for a test's skip reason."""


def refusal() -> str | None:
    """Why the container cannot run here, or None when it may (the kernel may still refuse at boot)."""
    if os.geteuid() != 0:
        return "booting systemd in a container needs root"
    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    if missing:
        return f"missing {', '.join(missing)} (util-linux, coreutils, iproute2)"
    if not SYSTEMD.exists():
        return f"systemd is not installed ({SYSTEMD})"
    filesystems = Path("/proc/filesystems").read_text()
    for fs in ("overlay", "cgroup2", "tmpfs", "devpts"):
        if not re.search(rf"\s{fs}$", filesystems, re.MULTILINE):
            return f"the kernel has no {fs} file system"
    if cgroup2_mount() is None:
        return "no cgroup2 hierarchy is mounted (systemd needs one for the container)"
    return None


def cgroup2_mount() -> Path | None:
    """Where the cgroup2 hierarchy is mounted (``/sys/fs/cgroup`` or, on a hybrid host, ``.../unified``)."""
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        fields = line.split(" - ", 1)
        if len(fields) == 2 and fields[1].split()[0] == "cgroup2":
            return Path(fields[0].split()[4])
    return None


def own_cgroup2() -> Path:
    """This process's cgroup2 directory."""
    mount = cgroup2_mount()
    assert mount is not None
    for line in Path("/proc/self/cgroup").read_text().splitlines():
        if line.startswith("0::"):
            return mount / line[3:].lstrip("/")
    raise Refused("this process is in no cgroup2 group")


@dataclass
class Container:
    """A booted container: its PID 1 (as the host sees it), and how to drive systemd in it."""

    pid: int
    base: Path
    cgroup: Path

    @property
    def root(self) -> Path:
        """The container's root directory, reachable from the host while PID 1 lives."""
        return Path(f"/proc/{self.pid}/root")

    def path(self, inside: str) -> Path:
        """A path in the container as the host reaches it."""
        return self.root / inside.lstrip("/")

    def run(
        self, *argv: str, timeout: float = 30.0, check: bool = True, env: dict[str, str] | None = None
    ) -> subprocess.CompletedProcess[str]:
        """Run a command in every namespace of the container, at its root."""
        command = ["nsenter", "-t", str(self.pid), "-m", "-u", "-i", "-n", "-p", "-r", "-w", "--", *argv]
        result = subprocess.run(
            command, capture_output=True, text=True, timeout=timeout, check=False, env=env
        )
        if check and result.returncode != 0:
            output = result.stdout + result.stderr
            raise AssertionError(f"{' '.join(argv)} in the container exited {result.returncode}:\n{output}")
        return result

    def run_in_network(
        self,
        argv: Sequence[str],
        *,
        timeout: float = 30.0,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
    ) -> subprocess.CompletedProcess[str]:
        """Run a host command (host files, host PID namespace) in the container's network namespace: a
        client reaching a daemon that listens on the container's loopback."""
        command = ["nsenter", "-t", str(self.pid), "-n", "--", *argv]
        return subprocess.run(
            command, capture_output=True, text=True, timeout=timeout, check=False, cwd=cwd, env=env
        )

    def systemctl(
        self, *args: str, timeout: float = 60.0, check: bool = True
    ) -> subprocess.CompletedProcess[str]:
        return self.run("systemctl", "--no-pager", *args, timeout=timeout, check=check)

    def show(self, unit: str, *properties: str) -> dict[str, str]:
        """``systemctl show`` of those properties, by name."""
        out = self.systemctl("show", unit, "--property", ",".join(properties)).stdout
        values = dict(line.split("=", 1) for line in out.splitlines() if "=" in line)
        return {p: values.get(p, "") for p in properties}

    def journal(self, unit: str | None = None, *, since: float = 0.0) -> str:
        """The journal of this boot (of one unit, with systemd's own lines about it), from ``since`` on
        (``time.monotonic()``: the container shares the host's monotonic clock)."""
        which = ["-u", unit] if unit else []
        self.run("journalctl", "--sync", check=False)  # what journald has received, written out
        out = self.run("journalctl", "-b", "--no-pager", "-o", "short-monotonic", *which, check=False).stdout
        return "".join(line for line in out.splitlines(keepends=True) if monotonic_stamp(line) >= since)

    def processes(self, unit: str) -> set[int]:
        """The host's PIDs of every process in ``unit``'s cgroup."""
        group = self.cgroup / "system.slice" / unit / "cgroup.procs"
        return {int(pid) for pid in group.read_text().split()} if group.exists() else set()

    def host_pid(self, inner_pid: int, unit: str) -> int:
        """The host's PID of the container's process ``inner_pid`` of ``unit`` (signals from outside)."""
        for pid in self.processes(unit):
            status = Path(f"/proc/{pid}/status").read_text()
            match = re.search(r"^NSpid:\s+(.*)$", status, re.MULTILINE)
            if match and int(match.group(1).split()[-1]) == inner_pid:
                return int(pid)
        raise AssertionError(f"no process {inner_pid} in {unit}")


def _hidden_by_fresh_mounts() -> list[Path]:
    """The checkout and the Python running it, where the container's fresh /tmp or /run would hide them."""
    found: list[Path] = []
    for path in (
        Path(__file__).resolve().parents[2],
        Path(sys.prefix).resolve(),
        Path(sys.base_prefix).resolve(),
    ):
        if path.parts[1:2] in (("tmp",), ("run",)) and not any(path.is_relative_to(f) for f in found):
            found.append(path)
    return found


@contextlib.contextmanager
def booted(*, masked: Sequence[str] = MASKED, timeout_s: float = BOOT_TIMEOUT_S) -> Iterator[Container]:
    """A container with systemd booted to ``basic.target`` (running or degraded), powered off and removed
    when the block ends. Raises ``Refused`` when this machine cannot make it."""
    reason = refusal()
    if reason is not None:
        raise Refused(reason)
    _remove_leftovers()
    base = Path(tempfile.mkdtemp(prefix=f"{_PREFIX}{os.getpid()}-"))
    marker = base / "host-tmp-marker"
    marker.write_text("the container must leave the host's /tmp alone\n")
    (base / "fs").mkdir()
    units = base / "seed" / "etc" / "systemd" / "system"
    units.mkdir(parents=True)
    for unit in masked:
        (units / unit).symlink_to("/dev/null")
    (base / "seed" / "etc" / "fstab").write_text("# the container mounts nothing from fstab\n")
    cgroup = own_cgroup2() / f"{_PREFIX}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    proc: subprocess.Popen[bytes] | None = None
    pid_one: int | None = None
    try:
        try:
            cgroup.mkdir()
        except OSError as e:
            raise Refused(f"cannot make a cgroup2 group for the container ({cgroup}): {e.strerror}") from e
        (base / "setup.sh").write_text(_SETUP)
        bounding = ",".join(f"-{cap}" for cap in DROPPED_CAPABILITIES)
        command = [
            "unshare",
            "--fork",
            "--pid",
            "--mount",
            "--uts",
            "--ipc",
            "--net",
            "--cgroup",
            "--propagation",
            "private",
            "--kill-child",
            "sh",
            str(base / "setup.sh"),
            str(base),
            bounding,
            *(str(p) for p in _hidden_by_fresh_mounts()),
        ]
        with (base / "boot.log").open("wb") as log:
            proc = subprocess.Popen(
                command,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                preexec_fn=_into_cgroup_and_die_with_parent(cgroup),
            )
        pid_one = _pid_one(proc, base)
        container = Container(pid_one, base, cgroup)
        _wait_until_booted(container, proc, timeout_s)
        if not marker.exists():  # never go on if the boot touched the host's /tmp
            raise RuntimeError(f"the container's boot removed {marker} from the host's /tmp: stop and look")
        yield container
    finally:
        if proc is not None:
            _power_off(proc, pid_one, cgroup)
        _remove_cgroup(cgroup)
        _remove_directory(base)


def _remove_leftovers() -> None:
    """The cgroup groups and host-side directories of containers whose test process was killed (its
    container died with it, by the parent-death chain, but nothing was left to remove these)."""
    places = [(own_cgroup2(), _remove_cgroup), (Path(tempfile.gettempdir()), _remove_directory)]
    for parent, remove in places:
        for path in parent.glob(f"{_PREFIX}*"):
            pid = path.name.removeprefix(_PREFIX).split("-", 1)[0]
            if pid.isdigit() and not Path(f"/proc/{pid}").exists():
                remove(path)


def _remove_directory(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def _into_cgroup_and_die_with_parent(cgroup: Path) -> Callable[[], None]:
    """Run in the child before it execs unshare: the container's cgroup becomes the root of its cgroup
    namespace, and the child dies when the test process does (unshare then takes the container down)."""

    def preexec() -> None:
        (cgroup / "cgroup.procs").write_text(str(os.getpid()))
        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL, 0, 0, 0)

    return preexec


def _pid_one(proc: subprocess.Popen[bytes], base: Path) -> int:
    """The host PID of the container's PID 1: unshare's one child."""
    deadline = time.monotonic() + 10.0
    children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise Refused(f"unshare exited {proc.returncode} at once: {_log(base)}")
        with contextlib.suppress(OSError):
            pids = children.read_text().split()
            if pids:
                return int(pids[0])
        time.sleep(0.01)
    raise AssertionError(f"unshare started no child in 10 s: {_log(base)}")


def _wait_until_booted(container: Container, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    state = ""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            log = _log(container.base)
            if "READY_TO_BOOT" not in log:  # the kernel refused a namespace, a mount or a cgroup
                raise Refused(f"the container could not be set up (exit {proc.returncode}): {log}")
            raise AssertionError(f"systemd in the container exited {proc.returncode}: {log}")
        if _chrooted(container.pid):
            result = container.run("systemctl", "is-system-running", timeout=10, check=False)
            state = result.stdout.strip()
            if state in ("running", "degraded"):
                return
        time.sleep(0.05)
    raise AssertionError(
        f"systemd in the container did not finish booting in {timeout_s:g} s (state {state!r}):\n"
        f"{_log(container.base)}{container.journal()[-4000:]}"
    )


def _chrooted(pid: int) -> bool:
    """Whether the container's PID 1 has left the host's root for the overlay (then systemd runs there)."""
    try:
        inside, host = os.stat(f"/proc/{pid}/root/"), os.stat("/")
    except OSError:
        return False
    return (inside.st_dev, inside.st_ino) != (host.st_dev, host.st_ino)


def _power_off(proc: subprocess.Popen[bytes], pid_one: int | None, cgroup: Path) -> None:
    """``systemctl poweroff`` (only once systemd runs on the overlay), then SIGKILL for what is left."""
    if proc.poll() is None and pid_one is not None and _chrooted(pid_one):
        nsenter = ["nsenter", "-t", str(pid_one), "-m", "-p", "-r", "-w", "systemctl", "poweroff"]
        with contextlib.suppress(subprocess.SubprocessError):
            subprocess.run(nsenter, capture_output=True, timeout=10, check=False)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=POWEROFF_TIMEOUT_S)
    if proc.poll() is None:
        proc.kill()  # --kill-child: PID 1 gets SIGKILL, and the whole PID namespace with it
        proc.wait(timeout=10)
    kill = cgroup / "cgroup.kill"
    if kill.exists():
        with contextlib.suppress(OSError):
            kill.write_text("1")


def _remove_cgroup(cgroup: Path) -> None:
    """The container's cgroup tree, leaves first, once its processes are gone."""
    if not cgroup.exists():
        return
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and "populated 1" in (cgroup / "cgroup.events").read_text():
        time.sleep(0.05)
    for directory, _, _ in os.walk(cgroup, topdown=False):
        with contextlib.suppress(OSError):
            os.rmdir(directory)


def monotonic_stamp(line: str) -> float:
    """The ``[  12.345678]`` stamp of a ``short-monotonic`` journal line (0 for lines without one)."""
    match = re.match(r"\[\s*(\d+\.\d+)\]", line)
    return float(match.group(1)) if match else 0.0


def _log(base: Path) -> str:
    try:
        return (base / "boot.log").read_text(errors="replace")
    except OSError:
        return ""
