"""The files ``dishbot security init`` writes for one robot and the people who command or watch it.

In ``DIR``: a certificate authority (``ca.pem``, ``ca.key``), a certificate and key per identity
(``NAME.pem``, ``NAME.key``; the robot's certificate names every address it is reached by), the password
dictionary (``passwords.txt``), the robot's config (``robot.toml``, for ``dishbot run --config``), one client
profile per operator and monitor (``NAME.profile.toml``) and, with a router, its config (``router.toml``).
Keys, passwords and profiles are written mode 0600. Nothing is written when any of the files exists, unless
asked to replace them all. Each certificate may be used only as its role needs (the router's only serves its
listener; see ``_USES``), and ``passwords.txt`` lists those who open links: the robot and the people.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import re
import secrets
import socket
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from daemon.errors import UsageError
from daemon.security import DEFAULT_PORT, Profile, TlsFiles, check_name, profile_text

CA_DAYS = 3650
IDENTITY_DAYS = 3 * 365
DICTIONARY = "passwords.txt"
ROUTER_NAME = "router"
_RESERVED = ("ca", ROUTER_NAME)  # ca.pem and ca.key are the CA's; the router's files are router.*
# What each identity's certificate may be used for (TLS checks the extended key usage): the router's only
# serves its listener, so a stolen router key opens no link to a robot (where the router role is granted by
# certificate alone); a person's only opens links; a robot listens and connects out to its router.
_USES = {
    "robot": [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
    "router": [ExtendedKeyUsageOID.SERVER_AUTH],
    "operator": [ExtendedKeyUsageOID.CLIENT_AUTH],
    "monitor": [ExtendedKeyUsageOID.CLIENT_AUTH],
}
_HOST = re.compile(
    r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)


@dataclass(frozen=True, slots=True)
class Identity:
    """Someone with a certificate: the robot, the router, an operator or a monitor."""

    name: str
    role: str
    addresses: tuple[str, ...] = ()  # host names and IP addresses the certificate is valid for


@dataclass(frozen=True, slots=True)
class SecurityPlan:
    """What ``dishbot security init`` was asked for, checked."""

    robot: Identity
    operators: tuple[Identity, ...]
    monitors: tuple[Identity, ...]
    router: Identity | None
    port: int

    @property
    def identities(self) -> tuple[Identity, ...]:
        router = (self.router,) if self.router is not None else ()
        return (self.robot, *router, *self.operators, *self.monitors)

    def endpoint(self) -> str:
        """Where clients connect: the router if there is one, else the robot's first address."""
        host = (self.router or self.robot).addresses[0]
        return f"tls/{_bracketed(host)}:{self.port}"

    def files(self, directory: Path) -> list[Path]:
        names = ["ca.pem", "ca.key", DICTIONARY, "robot.toml"]
        names += [f"{i.name}.{ext}" for i in self.identities for ext in ("pem", "key")]
        names += [f"{i.name}.profile.toml" for i in (*self.operators, *self.monitors)]
        if self.router is not None:
            names.append("router.toml")
        return [directory / n for n in names]


def plan(
    robot: str,
    *,
    addresses: Sequence[str] = (),
    operators: Sequence[str] = (),
    monitors: Sequence[str] = (),
    router: str | None = None,
    port: int = DEFAULT_PORT,
) -> SecurityPlan:
    """Check names and addresses; the robot's default addresses are this host's name and loopback."""
    if not (operators or monitors):
        raise UsageError("name at least one --operator or --monitor: nobody else may reach the robot")
    robot = _name(robot, "--robot")
    if not 1 <= port <= 65535:
        raise UsageError(f"--port {port}: choose 1-65535")
    hosts = tuple(_address(a) for a in addresses) or (socket.gethostname(), "localhost", "127.0.0.1")
    people = [(_name(n, "--operator"), "operator") for n in operators]
    people += [(_name(n, "--monitor"), "monitor") for n in monitors]
    seen: dict[str, str] = {robot: "the robot"}
    if router is not None:
        seen[ROUTER_NAME] = "the router"
    for name, role in people:
        if name in seen:
            raise UsageError(f"--{role} {name}: the name is already taken by {seen[name]}; names must differ")
        seen[name] = f"{role} {name}"
    return SecurityPlan(
        robot=Identity(robot, "robot", tuple(dict.fromkeys(hosts))),
        operators=tuple(Identity(n, r) for n, r in people if r == "operator"),
        monitors=tuple(Identity(n, r) for n, r in people if r == "monitor"),
        router=None if router is None else Identity(ROUTER_NAME, "router", (_address(router),)),
        port=port,
    )


def write(plan: SecurityPlan, directory: Path, *, force: bool = False) -> list[Path]:
    """Write everything into ``directory`` (created mode 0700); returns the files written."""
    files = plan.files(directory)
    existing = [p for p in files if p.exists()]
    if existing and not force:
        raise UsageError(
            f"{existing[0]} exists; nothing was written. --force replaces every file (a new CA: every robot, "
            "router and client then needs the new files)"
        )
    try:
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
        now = datetime.datetime.now(datetime.UTC)
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca_cert = _ca_certificate(ca_key, f"dishbot {plan.robot.name} CA", now)
        _write(directory / "ca.pem", _pem(ca_cert), private=False)
        _write(directory / "ca.key", _key_pem(ca_key), private=True)
        for identity in plan.identities:
            key = ec.generate_private_key(ec.SECP256R1())
            cert = _identity_certificate(identity, key, ca_key, ca_cert, now)
            _write(directory / f"{identity.name}.pem", _pem(cert), private=False)
            _write(directory / f"{identity.name}.key", _key_pem(key), private=True)
        # The router opens no link (its certificate only serves its listener), so it needs no password.
        passwords = {i.name: secrets.token_urlsafe(24) for i in plan.identities if i.role != "router"}
        _write(
            directory / DICTIONARY, "".join(f"{n}:{p}\n" for n, p in passwords.items()).encode(), private=True
        )
        _write(directory / "robot.toml", robot_config(plan).encode(), private=True)
        if plan.router is not None:
            _write(directory / "router.toml", router_config(plan).encode(), private=True)
        for person in (*plan.operators, *plan.monitors):
            profile = Profile(
                endpoint=plan.endpoint(),
                robot=plan.robot.name,
                tls=TlsFiles(Path("ca.pem"), Path(f"{person.name}.pem"), Path(f"{person.name}.key")),
                user=person.name,
                password=passwords[person.name],
                role=person.role,
            )
            comment = (
                f"dishbot profile: {person.role} {person.name} of robot {plan.robot.name}; it holds a "
                f"password, keep it private (with ca.pem, {person.name}.pem and {person.name}.key beside it)"
            )
            _write(
                directory / f"{person.name}.profile.toml",
                profile_text(profile, comment=comment).encode(),
                private=True,
            )
    except OSError as e:
        raise UsageError(f"cannot write into {directory}: {e.strerror} ({e.filename})") from e
    return files


def robot_config(plan: SecurityPlan) -> str:
    """``robot.toml``: the robot's security settings; the rest of its config may be added below."""
    robot = plan.robot
    lines = [
        f"# dishbot config of robot {robot.name} with remote access (written by `dishbot security init`).",
        "# Run it with `dishbot run --config robot.toml`; add the robot's other settings to this file.",
        "# File names are relative to this file's folder; it needs ca.pem, "
        f"{robot.name}.pem, {robot.name}.key and {DICTIONARY}.",
        f'robot_id = "{robot.name}"',
        "",
        "[zenoh]",
        f"listen = {_list(_listen(robot, plan.port))}",
    ]
    if plan.router is not None:
        lines.append(f'connect = ["{plan.endpoint()}"]')
    lines += _security_tables(robot.name)
    if plan.router is not None:
        lines.append(
            f'user = "{robot.name}"                        # to the router; password from the dictionary'
        )
    lines += [
        "",
        "[zenoh.access]",
        "enabled = true",
        f"operators = {_list(i.name for i in plan.operators)}",
        f"monitors = {_list(i.name for i in plan.monitors)}",
        f"routers = {_list([ROUTER_NAME] if plan.router is not None else [])}",
    ]
    return "\n".join(lines) + "\n"


def router_config(plan: SecurityPlan) -> str:
    """``router.toml``: for ``dishbot router --config router.toml``."""
    assert plan.router is not None
    lines = [
        "# dishbot router config (written by `dishbot security init`).",
        "# Run it with `dishbot router --config router.toml`.",
        f"# File names are relative to this file's folder; it needs ca.pem, {ROUTER_NAME}.pem, "
        f"{ROUTER_NAME}.key and {DICTIONARY}.",
        "",
        "[zenoh]",
        f"listen = {_list(_listen(plan.router, plan.port))}",
        *_security_tables(ROUTER_NAME),
        "",
        "[zenoh.access]",
        "enabled = true",
        f"operators = {_list(i.name for i in plan.operators)}",
        f"monitors = {_list(i.name for i in plan.monitors)}",
        f"robots = {_list([plan.robot.name])}",
    ]
    return "\n".join(lines) + "\n"


# --- helpers ------------------------------------------------------------------------------------------------


def _name(value: str, flag: str) -> str:
    try:
        name = check_name(value, flag)
    except ValueError as e:
        raise UsageError(str(e)) from e
    if name in _RESERVED:
        raise UsageError(f"{flag} {name}: the name is reserved for a file of its own; choose another")
    return name


def _address(value: str) -> str:
    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        if _HOST.match(value):
            return value
    raise UsageError(f"--address {value!r}: not an IP address or host name")


def _bracketed(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def _listen(identity: Identity, port: int) -> list[str]:
    """Each IP address, or every interface when the identity is known by host name (mutual TLS guards it)."""
    ips = [a for a in identity.addresses if _is_ip(a)]
    if len(ips) == len(identity.addresses):
        return [f"tls/{_bracketed(a)}:{port}" for a in ips]
    return [f"tls/0.0.0.0:{port}"]


def _is_ip(value: str) -> bool:
    try:
        ipaddress.ip_address(value)
    except ValueError:
        return False
    return True


def _security_tables(name: str) -> list[str]:
    return [
        "",
        "[zenoh.tls]",
        'root_ca_certificate = "ca.pem"',
        f'certificate = "{name}.pem"',
        f'private_key = "{name}.key"',
        "",
        "[zenoh.auth]",
        f'dictionary_file = "{DICTIONARY}"',
    ]


def _list(items: Iterable[str]) -> str:
    return "[" + ", ".join(f'"{i}"' for i in items) + "]"


def _ca_certificate(key: ec.EllipticCurvePrivateKey, name: str, now: datetime.datetime) -> x509.Certificate:
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CA_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )


def _identity_certificate(
    identity: Identity,
    key: ec.EllipticCurvePrivateKey,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    now: datetime.datetime,
) -> x509.Certificate:
    """The common name is the identity (Zenoh's access control matches it); the names are where it listens."""
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity.name)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=IDENTITY_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage(_USES[identity.role]), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
    )
    if identity.addresses:
        names: list[x509.GeneralName] = [
            x509.IPAddress(ipaddress.ip_address(a)) if _is_ip(a) else x509.DNSName(a)
            for a in identity.addresses
        ]
        builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    return builder.sign(ca_key, hashes.SHA256())


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _write(path: Path, data: bytes, *, private: bool) -> None:
    """Write ``data``; a private file is created 0600 from the start, never readable by others."""
    mode = 0o600 if private else 0o644
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, mode)  # an existing file (--force) keeps its old mode through O_CREAT
