"""Who may talk to a dishbot over Zenoh: endpoints, TLS, user/password, roles, and the clients' profiles.

Three layers, each enforced by Zenoh itself:

- **TLS with mutual authentication** (``[zenoh.tls]``): every ``tls/`` link is encrypted, and both ends show a
  certificate signed by the fleet's CA. A certificate's common name is its holder's identity.
- **User and password** (``[zenoh.auth]``): whoever opens a link names a user and proves the password found
  in the listening side's dictionary file (``user:password`` lines).
- **Roles** (``[zenoh.access]``): Zenoh access control, default deny. An *operator* may call every
  ``cmd/<verb>``; a *monitor* may subscribe and call ``cmd/status`` only; a *router* (on a robot) forwards for
  operators, matched by certificate alone on the link the robot opens to it (the router's certificate is
  for serving only, so it opens no link to a robot); a *robot* (on a router) serves its own
  ``dishbot/<id>/**``. Nobody else may do anything.

Loopback without security stays the default for local work; an endpoint reachable from other machines
without TLS is refused at start unless ``insecure`` is set (``exposure_error``). Client verbs read a *profile*
(``dishbot security init`` writes one per operator and monitor): the endpoint, the robot id, the identity's
certificate and key, the CA and the password.

This module is plain data and JSON for Zenoh's configuration: it imports neither Zenoh nor a crypto library,
so client verbs stay quick to start.
"""

from __future__ import annotations

import re
import stat
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any

from daemon.errors import ConfigError
from validation import convert, show, within
from validation.hosts import is_loopback

NAMESPACE = "dishbot"
# dishbot's own port ("DISH" on a phone keypad): not Zenoh's 7447 (zenohd, ROS 2's rmw_zenoh router, the
# Zenoh bridges) nor its scouting port 7446, and below the ports DDS (ROS 2) takes from 7400 up.
DEFAULT_PORT = 3474
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})\Z")
_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}\Z")
NAME_RULE = "1-64 letters, digits, '_' or '-'"
# The commands a query may address to many robots at once (dishbot/*/cmd/<verb>): looking at every robot and
# stopping every robot are safe in one go; starting or resetting robots nobody named is not.
FLEET_VERBS = ("status", "estop")
# The commands a monitor may send (access control lets nothing else through); an operator may send all.
MONITOR_VERBS = ("status",)

# Who may do what, seen from the node that enforces it (a robot's daemon or a router). Zenoh allows a message
# when one of the subject's rules *includes* its key expression, so wildcard queries such as
# dishbot/*/cmd/status are allowed by the patterns below and nothing broader is.
_EVERY_KEY = f"{NAMESPACE}/**"
_EVERY_COMMAND = f"{NAMESPACE}/*/cmd/**"
_STATUS = [f"{NAMESPACE}/*/cmd/{verb}" for verb in MONITOR_VERBS]
_WATCH_IN = ("declare_subscriber", "liveliness_query", "declare_liveliness_subscriber")
_WATCH_OUT = ("put", "liveliness_token", "declare_queryable")


def check_endpoint(value: object, name: str) -> str:
    """A Zenoh endpoint ``proto/host:port``; raises ``ConfigError`` naming ``name`` otherwise."""
    match = _ENDPOINT.match(value) if isinstance(value, str) else None
    if match is None or not 1 <= int(match.group(3)) <= 65535:
        raise ConfigError(
            f"{name}: {show(value)} is not a Zenoh endpoint like tcp/127.0.0.1:{DEFAULT_PORT} "
            "(protocol tcp, udp, tls, quic or ws; port 1-65535)"
        )
    return str(value)


def check_key(value: object, name: str) -> str:
    """A plain Zenoh key (``a/b/c``: no wildcards, no empty chunk); raises ``ConfigError`` naming ``name``."""
    if (
        not isinstance(value, str)
        or not value
        or any(c in value for c in "*$?#")
        or value.startswith("/")
        or value.endswith("/")
        or "//" in value
    ):
        raise ConfigError(f"{name}: {show(value)} is not a plain Zenoh key (no wildcards)")
    return value


def endpoint_protocol(endpoint: str) -> str:
    return endpoint.split("/", 1)[0]


def endpoint_host(endpoint: str) -> str:
    """The host part of ``proto/host:port`` (an IPv6 address without its brackets)."""
    host = endpoint.split("/", 1)[1].rsplit(":", 1)[0]
    return host[1:-1] if host.startswith("[") else host


def check_name(value: object, name: str) -> str:
    """A robot id or identity name: a Zenoh key chunk, a certificate common name, a user and a file name."""
    if not isinstance(value, str) or not _NAME.match(value):
        raise ConfigError(f"{name}: {show(value)} is not a valid name; use {NAME_RULE}")
    return value


def check_robot(value: object, name: str, *, many: bool = False) -> str:
    """A robot id as a client names it; with ``many`` also ``*`` (every robot that answers)."""
    if many and value == "*":
        return "*"
    if not isinstance(value, str) or not _NAME.match(value):
        extra = " (or '*' for every robot)" if many else ""
        raise ConfigError(f"{name}: {show(value)} is not a robot id; use {NAME_RULE}{extra}")
    return value


@dataclass(frozen=True, slots=True)
class TlsFiles:
    """The CA that signs everyone, and this node's certificate and private key (PEM files)."""

    root_ca_certificate: Path | None = None
    certificate: Path | None = None
    private_key: Path | None = None

    @property
    def enabled(self) -> bool:
        return self.root_ca_certificate is not None

    def resolved(self, base: Path) -> TlsFiles:
        return TlsFiles(*(None if p is None else base / p for p in _tls_paths(self)))


@dataclass(frozen=True, slots=True)
class Auth:
    """User/password authentication: whom this node checks (``dictionary_file``) and who it says it is."""

    dictionary_file: Path | None = None
    user: str = ""
    password: str = field(default="", repr=False)

    def resolved(self, base: Path) -> Auth:
        return replace(
            self, dictionary_file=None if self.dictionary_file is None else base / self.dictionary_file
        )


@dataclass(frozen=True, slots=True)
class Access:
    """Roles by identity name (certificate common name and user name); ``enabled`` turns on default deny."""

    enabled: bool = False
    operators: tuple[str, ...] = ()
    monitors: tuple[str, ...] = ()
    routers: tuple[str, ...] = ()
    robots: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for role in ("operators", "monitors", "routers", "robots"):
            names = getattr(self, role)
            for i, name in enumerate(names):
                check_name(name, f"{role}[{i}]")
            twice = next((n for n in names if names.count(n) > 1), None)
            if twice is not None:
                raise ConfigError(f"{role}: {twice!r} is listed twice")


@dataclass(frozen=True, slots=True)
class ZenohConfig:
    """The daemon's (or router's) Zenoh session: endpoints and security."""

    listen: tuple[str, ...]
    connect: tuple[str, ...]
    insecure: bool = False
    tls: TlsFiles = TlsFiles()
    auth: Auth = Auth()
    access: Access = Access()
    lease_s: float = 10.0

    def resolved(self, base: Path) -> ZenohConfig:
        """Relative file names taken relative to ``base`` (the config file's folder)."""
        return replace(self, tls=self.tls.resolved(base), auth=self.auth.resolved(base))


@dataclass(frozen=True, slots=True)
class _TlsTable:
    """``[zenoh.tls]`` and a profile's ``[tls]``: PEM file names ("" for none)."""

    root_ca_certificate: str = ""
    certificate: str = ""
    private_key: str = ""

    def files(self) -> TlsFiles:
        return TlsFiles(
            *(Path(p) if p else None for p in (self.root_ca_certificate, self.certificate, self.private_key))
        )


@dataclass(frozen=True, slots=True)
class _AuthTable:
    """``[zenoh.auth]`` and a profile's ``[auth]``."""

    dictionary_file: str = ""
    user: str = ""
    password: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        if self.user:
            check_name(self.user, "user")


@dataclass(frozen=True, slots=True)
class _ZenohTable:
    """``[zenoh]``, declared once for the validator (``validation.convert``)."""

    listen: tuple[str, ...]
    connect: tuple[str, ...]
    insecure: bool = False
    lease_s: Annotated[float, within(1.0, 60.0)] = 10.0
    tls: _TlsTable = _TlsTable()
    auth: _AuthTable = _AuthTable()
    access: Access = Access()

    def __post_init__(self) -> None:
        for kind in ("listen", "connect"):
            for i, endpoint in enumerate(getattr(self, kind)):
                check_endpoint(endpoint, f"{kind}[{i}]")


@dataclass(frozen=True, slots=True)
class _ProfileTable:
    """A client profile file."""

    endpoint: str
    robot: str
    role: str = ""
    tls: _TlsTable = _TlsTable()
    auth: _AuthTable = _AuthTable()

    def __post_init__(self) -> None:
        check_endpoint(self.endpoint, "endpoint")
        check_robot(self.robot, "robot")


def parse_zenoh(section: Mapping[str, Any], where: str = "zenoh") -> ZenohConfig:
    """The ``[zenoh]`` table, checked: endpoints, TLS files that go together, roles that need identities."""
    table: _ZenohTable = convert(section, _ZenohTable, name=where, error=ConfigError)
    tls = table.tls.files()
    a = table.auth
    auth = Auth(Path(a.dictionary_file) if a.dictionary_file else None, a.user, a.password)
    access = table.access
    listen, connect = table.listen, table.connect
    missing = _missing_tls(tls)
    if missing:
        raise ConfigError(
            f"{where}.tls: set root_ca_certificate, certificate and private_key together "
            f"(missing {', '.join(missing)})"
        )
    for kind, endpoints in (("listen", listen), ("connect", connect)):
        for n, endpoint in enumerate(endpoints):
            missing_tls = tls_missing(endpoint, tls, where=where)
            if missing_tls:
                raise ConfigError(f"{where}.{kind}[{n}]: {missing_tls}")
    if auth.password and not auth.user:
        raise ConfigError(f"{where}.auth.password: set {where}.auth.user too (a password belongs to a user)")
    if access.enabled and not (tls.enabled or auth.dictionary_file is not None):
        raise ConfigError(
            f"{where}.access: roles need identities; set {where}.tls (certificate common names) or "
            f"{where}.auth.dictionary_file (user names)"
        )
    return ZenohConfig(listen, connect, table.insecure, tls, auth, access, table.lease_s)


def tls_missing(endpoint: str, tls: TlsFiles, *, where: str = "zenoh") -> str:
    """Why ``endpoint`` cannot work with these TLS files ("" when it can: not TLS, or TLS configured)."""
    if endpoint_protocol(endpoint) not in ("tls", "quic") or tls.enabled:
        return ""
    return (
        f"{endpoint} needs {where}.tls (root_ca_certificate, certificate, private_key); "
        "`dishbot security init` writes them"
    )


def check_files(zenoh: ZenohConfig, where: str = "zenoh") -> None:
    """The configured security files exist, and private ones are not readable by everybody."""
    for name, path in (
        ("tls.root_ca_certificate", zenoh.tls.root_ca_certificate),
        ("tls.certificate", zenoh.tls.certificate),
    ):
        _readable(path, f"{where}.{name}")
    _private(zenoh.tls.private_key, f"{where}.tls.private_key")
    _private(zenoh.auth.dictionary_file, f"{where}.auth.dictionary_file")
    if zenoh.auth.user and not own_password(zenoh.auth):
        raise ConfigError(
            f"{where}.auth.user: {zenoh.auth.user!r} has no password; set {where}.auth.password or give the "
            f"user a line in {where}.auth.dictionary_file"
        )


def own_password(auth: Auth) -> str:
    """This node's password: ``auth.password``, else its user's line in the dictionary file."""
    if auth.password or not auth.user or auth.dictionary_file is None:
        return auth.password
    return read_dictionary(auth.dictionary_file).get(auth.user, "")


def read_dictionary(path: Path) -> dict[str, str]:
    """A Zenoh user/password dictionary: ``user:password`` per line."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"cannot read the password dictionary {path}: {e.strerror}") from e
    entries = {}
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep or not _NAME.match(user) or not password:
            raise ConfigError(f"{path} line {number}: expected user:password with a user of {NAME_RULE}")
        entries[user] = password
    return entries


def exposure_error(listen: Sequence[str], connect: Sequence[str], zenoh: ZenohConfig) -> str | None:
    """Why these endpoints would let other machines command the arm without TLS, or None when they do not.

    A ``tls/`` endpoint is always mutually authenticated (both ends show a certificate of the CA), so only
    plain endpoints beyond loopback are exposed. Raises ``ConfigError`` for a TLS endpoint without the TLS
    files, which could not open at all."""
    for kind, endpoints in (("listen", listen), ("connect", connect)):
        for endpoint in endpoints:
            missing_tls = tls_missing(endpoint, zenoh.tls)
            if missing_tls:
                raise ConfigError(f"{kind} {missing_tls}")
            if is_loopback(endpoint_host(endpoint)) or (
                endpoint_protocol(endpoint) == "tls" and zenoh.tls.enabled
            ):
                continue
            return (
                f"zenoh {kind} {endpoint} is reachable from other machines without TLS: anyone who reaches "
                "it could command the arm; use a tls/ endpoint with [zenoh.tls] (`dishbot security init` "
                "writes one), or set zenoh.insecure = true (--insecure) on a network that is yours alone"
            )
    return None


def node_settings(zenoh: ZenohConfig) -> dict[str, object]:
    """Zenoh configuration entries (key → JSON value) for a daemon or a router with this section."""
    out: dict[str, object] = {"transport/link/tx/lease": round(zenoh.lease_s * 1000)}
    if zenoh.tls.enabled:
        out.update(_tls_settings(zenoh.tls, listening=True))  # the endpoints may come from the command line
    if zenoh.auth.dictionary_file is not None:
        out["transport/auth/usrpwd/dictionary_file"] = str(zenoh.auth.dictionary_file)
    if zenoh.auth.user:  # check_files made sure there is a password
        out["transport/auth/usrpwd/user"] = zenoh.auth.user
        out["transport/auth/usrpwd/password"] = own_password(zenoh.auth)
    if zenoh.access.enabled:
        out["access_control"] = access_control(
            zenoh.access,
            by_certificate=zenoh.tls.enabled,
            by_user=zenoh.auth.dictionary_file is not None,
        )
    return out


def access_control(access: Access, *, by_certificate: bool, by_user: bool) -> dict[str, object]:
    """Zenoh's ``access_control`` section for these roles: default deny, one subject per identity.

    An identity is matched by its certificate's common name and/or its user name (both when both are
    configured): a stolen password without the key, or a key without the password, is not enough."""
    if not (by_certificate or by_user):
        raise ConfigError("zenoh.access: roles need certificate common names or user names to match")
    rules = [
        _rule("watch_in", _WATCH_IN, "ingress", [_EVERY_KEY]),
        _rule("watch_out", _WATCH_OUT, "egress", [_EVERY_KEY]),
        _rule("command_in", ("query",), "ingress", [_EVERY_COMMAND]),
        _rule("command_out", ("reply",), "egress", [_EVERY_COMMAND]),
        _rule("status_in", ("query",), "ingress", _STATUS),
        _rule("status_out", ("reply",), "egress", _STATUS),
        _rule("robot_out", ("query",), "egress", [_EVERY_COMMAND]),
        _rule("robot_watch_out", _WATCH_IN, "egress", [_EVERY_KEY]),
    ]
    subjects: list[dict[str, object]] = []
    policies: list[dict[str, object]] = []
    grants = {
        "operator": ["watch_in", "watch_out", "command_in", "command_out"],
        "router": ["watch_in", "watch_out", "command_in", "command_out"],
        "monitor": ["watch_in", "watch_out", "status_in", "status_out"],
    }
    if access.routers and not by_certificate:
        raise ConfigError("zenoh.access.routers: a router is known by its certificate; set zenoh.tls")
    for role, names in (
        ("operator", access.operators),
        ("monitor", access.monitors),
        ("router", access.routers),
    ):
        for name in names:
            # A router is connected to, not connecting: it shows its certificate but sends no user name.
            subjects.append(_subject(f"{role}-{name}", name, by_certificate, by_user and role != "router"))
            policies.append({"rules": grants[role], "subjects": [f"{role}-{name}"]})
    for name in access.robots:
        # A robot serves its own keys only: it cannot publish or answer as another robot.
        rules.append(
            _rule(
                f"serve-{name}",
                ("put", "declare_queryable", "liveliness_token", "reply"),
                "ingress",
                [f"{NAMESPACE}/{name}/**"],
            )
        )
        subjects.append(_subject(f"robot-{name}", name, by_certificate, by_user))
        policies.append(
            {"rules": [f"serve-{name}", "robot_out", "robot_watch_out"], "subjects": [f"robot-{name}"]}
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def role_may(role: str, verb: str) -> bool:
    """Whether an identity of ``role`` (a profile's ``role``; "" when unknown) may send ``verb``: a monitor
    only its few, anyone else whatever the robot's access control lets through."""
    return verb in MONITOR_VERBS if role == "monitor" else True


@dataclass(frozen=True, slots=True)
class Profile:
    """What a client verb needs to reach a robot: where, which robot, and as whom."""

    endpoint: str
    robot: str
    tls: TlsFiles = TlsFiles()
    user: str = ""
    password: str = field(default="", repr=False)
    role: str = ""

    def settings(self) -> dict[str, object]:
        """Zenoh configuration entries (key → JSON value) for a client session with this identity."""
        out: dict[str, object] = {}
        if self.tls.enabled:
            out.update(_tls_settings(self.tls, listening=False))
        if self.user:
            out["transport/auth/usrpwd/user"] = self.user
            out["transport/auth/usrpwd/password"] = self.password
        return out


def load_profile(path: Path) -> Profile:
    """A client profile (TOML); relative file names are taken relative to the profile's folder."""
    where = f"profile {path}"
    try:
        mode = path.stat().st_mode
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{where}: cannot read it: {e.strerror}") from e
    if mode & stat.S_IROTH:
        raise ConfigError(f"{where}: readable by every user, and it holds a password; chmod 600 {path}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where} is not valid TOML: {e}") from e
    table: _ProfileTable = convert(
        data, _ProfileTable, error=ConfigError, prefix=f"{where}: ", root="the profile"
    )
    endpoint, robot, role = table.endpoint, table.robot, table.role
    tls = table.tls.files()
    user, password = table.auth.user, table.auth.password
    missing = _missing_tls(tls)
    if missing:
        raise ConfigError(
            f"{where}: [tls] needs root_ca_certificate, certificate and private_key together "
            f"(missing {', '.join(missing)})"
        )
    if endpoint_protocol(endpoint) == "tls" and not tls.enabled:
        raise ConfigError(f"{where}: endpoint {endpoint} needs the [tls] files")
    if bool(user) != bool(password):
        raise ConfigError(f"{where}: [auth] needs both user and password")
    tls = tls.resolved(path.parent)
    _readable(tls.root_ca_certificate, f"{where}: tls.root_ca_certificate")
    _readable(tls.certificate, f"{where}: tls.certificate")
    _private(tls.private_key, f"{where}: tls.private_key")
    return Profile(endpoint, robot, tls, user, password, role)


def profile_text(profile: Profile, *, comment: str) -> str:
    """A profile file as ``load_profile`` reads it (file names as given, usually relative)."""
    lines = [f"# {comment}", f'endpoint = "{profile.endpoint}"', f'robot = "{profile.robot}"']
    if profile.role:
        lines.append(f'role = "{profile.role}"')
    if profile.tls.enabled:
        lines += ["", "[tls]"]
        for key, path in zip(_TLS_KEYS, _tls_paths(profile.tls), strict=True):
            lines.append(f'{key} = "{path}"')
    if profile.user:
        lines += ["", "[auth]", f'user = "{profile.user}"', f'password = "{profile.password}"']
    return "\n".join(lines) + "\n"


# --- helpers ------------------------------------------------------------------------------------------------


_TLS_KEYS = ("root_ca_certificate", "certificate", "private_key")


def _tls_paths(tls: TlsFiles) -> tuple[Path | None, Path | None, Path | None]:
    return (tls.root_ca_certificate, tls.certificate, tls.private_key)


def _missing_tls(tls: TlsFiles) -> list[str]:
    """The TLS keys left empty when some are set (none set: TLS is off, nothing is missing)."""
    paths = _tls_paths(tls)
    if all(p is None for p in paths):
        return []
    return [key for key, p in zip(_TLS_KEYS, paths, strict=True) if p is None]


def _tls_settings(tls: TlsFiles, *, listening: bool) -> dict[str, object]:
    out: dict[str, object] = {
        "transport/link/tls/root_ca_certificate": str(tls.root_ca_certificate),
        "transport/link/tls/connect_certificate": str(tls.certificate),
        "transport/link/tls/connect_private_key": str(tls.private_key),
        # Both ends show a certificate of the CA: the listener learns the client's common name (its
        # identity for access control), and nobody without a certificate gets a link at all.
        "transport/link/tls/enable_mtls": True,
        "transport/link/tls/verify_name_on_connect": True,
    }
    if listening:
        out["transport/link/tls/listen_certificate"] = str(tls.certificate)
        out["transport/link/tls/listen_private_key"] = str(tls.private_key)
    return out


def _rule(rule_id: str, messages: Sequence[str], flow: str, keys: Sequence[str]) -> dict[str, object]:
    return {
        "id": rule_id,
        "messages": list(messages),
        "flows": [flow],
        "permission": "allow",
        "key_exprs": list(keys),
    }


def _subject(subject_id: str, name: str, by_certificate: bool, by_user: bool) -> dict[str, object]:
    subject: dict[str, object] = {"id": subject_id}
    if by_certificate:
        subject["cert_common_names"] = [name]
    if by_user:
        subject["usernames"] = [name]
    return subject


def _readable(path: Path | None, name: str) -> None:
    if path is None:
        return
    try:
        path.read_bytes()
    except OSError as e:
        raise ConfigError(f"{name}: cannot read {path}: {e.strerror}") from e


def _private(path: Path | None, name: str) -> None:
    if path is None:
        return
    _readable(path, name)
    if path.stat().st_mode & stat.S_IROTH:
        raise ConfigError(f"{name}: {path} is readable by every user; chmod 600 {path} (or 640 for a group)")
