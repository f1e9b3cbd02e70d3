"""TLS, passwords and roles on real Zenoh sessions over loopback: who gets in, who may do what, and every
class of bad input to ``dishbot security init``, the ``[zenoh]`` config and the profiles."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from bench.remote import python_env
from cli.main import main
from daemon.app import RunOptions, listen_in_use, tolerated_exposure
from daemon.config import load_config
from daemon.errors import ConfigError, UsageError
from daemon.security import exposure_error, load_profile, parse_zenoh
from daemon.zenoh_session import transport_limit_bytes
from tests.daemon.conftest import free_port
from tests.daemon.daemons import ask, cli, daemon, robot_config, until_state

ROBOT = "r1"


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A robot, an operator and a monitor on a free loopback TLS port, and a foreign CA's operator."""
    port = str(free_port())
    home = tmp_path_factory.mktemp("keys")
    for name in ("site", "foreign"):
        argv = ["security", "init", str(home / name), "--robot", ROBOT, "--address", "127.0.0.1"]
        assert main([*argv, "--operator", "alice", "--monitor", "bob", "--port", port]) == 0
    return home


def _profile(keys: Path, name: str) -> str:
    return str(keys / "site" / f"{name}.profile.toml")


def _copy(keys: Path, tmp_path: Path, source: str, name: str, edit: tuple[str, str] | None = None) -> str:
    """A copy of alice's profile (and its files) from ``source`` in ``tmp_path/name``, one line changed."""
    folder, target = keys / source, tmp_path / name
    target.mkdir()
    for file in ("alice.pem", "alice.key", "alice.profile.toml", "ca.pem"):
        shutil.copy(folder / file, target / file)
    text = (target / "alice.profile.toml").read_text()
    if source == "foreign":  # point it at the site's robot
        site = (keys / "site" / "alice.profile.toml").read_text()
        text = text.replace(text.split("\n")[1], site.split("\n")[1])
    if edit is not None:
        text = "\n".join(edit[1] if line.startswith(edit[0]) else line for line in text.split("\n"))
    path = target / f"{name}.profile.toml"
    path.write_text(text)
    path.chmod(0o600)
    return str(path)


def test_init_writes_a_ca_identities_passwords_robot_config_and_profiles(keys: Path) -> None:
    site = keys / "site"
    names = sorted(p.name for p in site.iterdir())
    assert names == sorted(
        [
            "ca.pem",
            "ca.key",
            "passwords.txt",
            "robot.toml",
            "r1.pem",
            "r1.key",
            "alice.pem",
            "alice.key",
            "bob.pem",
            "bob.key",
            "alice.profile.toml",
            "bob.profile.toml",
        ]
    )
    for private in (
        "ca.key",
        "r1.key",
        "alice.key",
        "bob.key",
        "passwords.txt",
        "robot.toml",
        "alice.profile.toml",
    ):
        assert stat.S_IMODE((site / private).stat().st_mode) == 0o600, private
    ca = x509.load_pem_x509_certificate((site / "ca.pem").read_bytes())
    robot = x509.load_pem_x509_certificate((site / "r1.pem").read_bytes())
    robot.verify_directly_issued_by(ca)
    assert robot.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "r1"
    names_in = robot.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(a) for a in names_in.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
    alice = x509.load_pem_x509_certificate((site / "alice.pem").read_bytes())
    alice.verify_directly_issued_by(ca)
    assert alice.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "alice"
    config = load_config(site / "robot.toml")
    assert config.robot_id == "r1"
    assert config.zenoh.tls.certificate == site / "r1.pem"
    assert (config.zenoh.access.operators, config.zenoh.access.monitors) == (("alice",), ("bob",))
    profile = load_profile(site / "bob.profile.toml")
    assert (profile.robot, profile.user, profile.role) == ("r1", "bob", "monitor")
    assert profile.endpoint == config.zenoh.listen[0]
    assert (
        profile.password
        == dict(line.split(":", 1) for line in (site / "passwords.txt").read_text().splitlines())["bob"]
    )


def test_init_refuses_to_overwrite_without_force(
    keys: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "k"
    argv = ["security", "init", str(target), "--robot", "r2", "--operator", "ann"]
    assert main(argv) == 0
    before = (target / "ca.pem").read_bytes()
    capsys.readouterr()
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"dishbot security: error: {target / 'ca.pem'} exists; nothing was written. --force replaces every "
        "file (a new CA: every robot, router and client then needs the new files)\n"
    )
    assert (target / "ca.pem").read_bytes() == before
    assert main([*argv, "--force"]) == 0
    assert (target / "ca.pem").read_bytes() != before
    assert stat.S_IMODE((target / "ann.key").stat().st_mode) == 0o600


@pytest.mark.parametrize(
    ("extra", "error"),
    [
        (
            ["--robot", "dish$bot", "--operator", "a"],
            "--robot: 'dish$bot' is not a valid name; use 1-64 letters, digits, '_' or '-'",
        ),
        (
            ["--robot", "r1", "--operator", "a b"],
            "--operator: 'a b' is not a valid name; use 1-64 letters, digits, '_' or '-'",
        ),
        (
            ["--robot", "r1", "--operator", "ca"],
            "--operator ca: the name is reserved for a file of its own; choose another",
        ),
        (
            ["--robot", "r1", "--operator", "a", "--monitor", "a"],
            "--monitor a: the name is already taken by operator a; names must differ",
        ),
        (
            ["--robot", "r1", "--operator", "r1"],
            "--operator r1: the name is already taken by the robot; names must differ",
        ),
        (["--robot", "r1"], "name at least one --operator or --monitor: nobody else may reach the robot"),
        (
            ["--robot", "r1", "--operator", "a", "--address", "robot_1.lan"],
            "--address 'robot_1.lan': not an IP address or host name",
        ),
        (["--robot", "r1", "--operator", "a", "--port", "0"], "--port 0: choose 1-65535"),
    ],
)
def test_init_bad_input_is_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], error: str
) -> None:
    assert main(["security", "init", str(tmp_path / "k"), *extra]) == 2
    assert capsys.readouterr().err == f"dishbot security: error: {error}\n"
    assert not (tmp_path / "k").exists()


@pytest.mark.parametrize(
    ("zenoh_table", "error"),
    [
        (
            {"listen": ["tls/127.0.0.1:3474"]},
            "zenoh.listen[0]: tls/127.0.0.1:3474 needs zenoh.tls (root_ca_certificate, certificate, "
            "private_key); `dishbot security init` writes them",
        ),
        (
            {"tls": {"root_ca_certificate": "ca.pem"}},
            "zenoh.tls: set root_ca_certificate, certificate and private_key together "
            "(missing certificate, private_key)",
        ),
        (
            {"tls": {"ca": "ca.pem"}},
            "zenoh.tls.ca: unknown key in zenoh.tls "
            "(known keys: certificate, private_key, root_ca_certificate)",
        ),
        (
            {"access": {"enabled": True, "operators": ["alice"]}},
            "zenoh.access: roles need identities; set zenoh.tls (certificate common names) or "
            "zenoh.auth.dictionary_file (user names)",
        ),
        (
            {"access": {"operators": ["alice smith"]}},
            "zenoh.access.operators[0]: 'alice smith' is not a valid name; "
            "use 1-64 letters, digits, '_' or '-'",
        ),
        (
            {"auth": {"password": "x"}},
            "zenoh.auth.password: set zenoh.auth.user too (a password belongs to a user)",
        ),
        ({"insecure": "yes"}, "zenoh.insecure: expected true or false, got 'yes'"),
        ({"access": {"monitors": ["bob", "bob"]}}, "zenoh.access.monitors: 'bob' is listed twice"),
        (
            {"auth": {"user": "r1"}},
            "zenoh.auth.user: 'r1' has no password; set zenoh.auth.password or give the user a line in "
            "zenoh.auth.dictionary_file",
        ),
        ({"lease_s": 0.1}, "zenoh.lease_s: 0.1 is out of range; allowed [1, 60]"),
        (
            {"connect": ["tcp/robot:99999"]},
            "zenoh.connect[0]: 'tcp/robot:99999' is not a Zenoh endpoint like tcp/127.0.0.1:3474 "
            "(protocol tcp, udp, tls, quic or ws; port 1-65535)",
        ),
    ],
)
def test_each_bad_zenoh_setting_is_refused_with_its_name(zenoh_table: dict[str, object], error: str) -> None:
    with pytest.raises(ConfigError) as e:
        load_config(overrides={"zenoh": zenoh_table})
    assert str(e.value) == error


def test_security_files_must_exist_and_keys_must_not_be_world_readable(keys: Path, tmp_path: Path) -> None:
    site = tmp_path / "site"
    shutil.copytree(keys / "site", site)
    (site / "r1.key").chmod(0o644)
    with pytest.raises(ConfigError) as e:
        load_config(site / "robot.toml")
    assert str(e.value) == (
        f"zenoh.tls.private_key: {site / 'r1.key'} is readable by every user; chmod 600 {site / 'r1.key'} "
        "(or 640 for a group)"
    )
    (site / "r1.key").chmod(0o600)
    (site / "r1.pem").unlink()
    with pytest.raises(ConfigError) as e:
        load_config(site / "robot.toml")
    assert str(e.value) == f"zenoh.tls.certificate: cannot read {site / 'r1.pem'}: No such file or directory"


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ('robot = "r1"\n', "endpoint: missing"),
        (
            'endpoint = "tls/127.0.0.1:3474"\nrobot = "r1"\n',
            "endpoint tls/127.0.0.1:3474 needs the [tls] files",
        ),
        (
            'endpoint = "tcp/127.0.0.1:3474"\nrobot = "a#b"\n',
            "robot: 'a#b' is not a robot id; use 1-64 letters, digits, '_' or '-'",
        ),
        (
            'endpoint = "tcp/127.0.0.1:3474"\nrobot = "r1"\n[auth]\nuser = "alice"\n',
            "[auth] needs both user and password",
        ),
        (
            'endpoint = "tcp/127.0.0.1:3474"\nrobot = "r1"\ncolour = "red"\n',
            "colour: unknown key in the profile (known keys: auth, endpoint, robot, role, tls)",
        ),
        ("endpoint = \n", "is not valid TOML: Invalid value (at line 1, column 12)"),
    ],
)
def test_each_bad_profile_is_a_one_line_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, error: str
) -> None:
    path = tmp_path / "p.profile.toml"
    path.write_text(text)
    path.chmod(0o600)
    assert main(["status", "--profile", str(path)]) == 2
    separator = " " if error.startswith("is not") else ": "
    assert capsys.readouterr().err == f"dishbot status: error: profile {path}{separator}{error}\n"


def test_a_profile_readable_by_everyone_or_missing_is_refused(
    keys: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = Path(_copy(keys, tmp_path, "site", "open"))
    path.chmod(0o644)
    assert main(["--profile", str(path), "status"]) == 2
    assert capsys.readouterr().err == (
        f"dishbot status: error: profile {path}: readable by every user, and it holds a password; "
        f"chmod 600 {path}\n"
    )
    os.environ["DISHBOT_PROFILE"] = str(tmp_path / "nowhere.toml")
    try:
        assert main(["status"]) == 2
    finally:
        del os.environ["DISHBOT_PROFILE"]
    assert capsys.readouterr().err == (
        f"dishbot status: error: profile {tmp_path / 'nowhere.toml'}: cannot read it: "
        "No such file or directory\n"
    )


@pytest.mark.parametrize(
    ("listen", "connect", "exposed"),
    [
        (["tcp/127.0.0.1:3474"], [], None),
        (["tcp/[::1]:3474", "tcp/localhost:3474"], [], None),
        (["tcp/0.0.0.0:3474"], [], "listen tcp/0.0.0.0:3474"),
        (["tcp/127.0.0.1:3474"], ["tcp/10.1.2.3:3474"], "connect tcp/10.1.2.3:3474"),
        (["udp/192.168.1.4:3474"], [], "listen udp/192.168.1.4:3474"),
    ],
)
def test_endpoints_beyond_loopback_without_tls_are_exposed(
    listen: list[str], connect: list[str], exposed: str | None
) -> None:
    problem = exposure_error(listen, connect, load_config().zenoh)
    if exposed is None:
        assert problem is None
    else:
        assert problem == (
            f"zenoh {exposed} is reachable from other machines without TLS: anyone who reaches it could "
            "command the arm; use a tls/ endpoint with [zenoh.tls] (`dishbot security init` writes one), or "
            "set zenoh.insecure = true (--insecure) on a network that is yours alone"
        )


def test_a_tls_endpoint_on_every_interface_is_not_exposed(keys: Path) -> None:
    config = load_config(keys / "site" / "robot.toml")
    assert exposure_error(["tls/0.0.0.0:3474"], [], config.zenoh) is None


def test_run_refuses_an_exposed_endpoint_before_starting_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = [
        "run",
        "--sim",
        "--world",
        "kinematic",
        "--record-dir",
        str(tmp_path),
        "--listen",
        "tcp/0.0.0.0:3474",
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        "dishbot run: error: zenoh listen tcp/0.0.0.0:3474 is reachable from other machines"
    )
    assert err.count("\n") == 1
    assert not any(tmp_path.iterdir())  # no recording: nothing started


def test_run_refuses_a_listen_port_in_use_before_starting_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A second daemon on one machine (the default port is the same for every run) fails before any
    servo's torque is on, with the fix named."""
    with socket.create_server(("127.0.0.1", 0)) as other:
        port = other.getsockname()[1]
        argv = ["run", "--sim", "--world", "kinematic", "--record-dir", str(tmp_path)]
        assert main([*argv, "--listen", f"tcp/127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"dishbot run: error: cannot listen on tcp/127.0.0.1:{port}: the address is in use (another dishbot "
        "running on this machine? give this one a free port with --listen tcp/127.0.0.1:PORT)\n"
    )
    assert not any(tmp_path.iterdir())  # no recording: nothing started


def test_a_listen_port_is_in_use_only_while_something_listens_on_it() -> None:
    with socket.create_server(("127.0.0.1", 0)) as other:
        port = other.getsockname()[1]
        assert listen_in_use([f"tcp/127.0.0.1:{port}"]) is not None
        assert listen_in_use([f"tls/127.0.0.1:{port}?x=1"]) is not None  # options after the address
        assert listen_in_use([f"tcp/0.0.0.0:{port}"]) is not None  # every interface takes loopback's too
        assert listen_in_use([f"udp/127.0.0.1:{port}", "tcp/127.0.0.1:0"]) is None  # not checked
    # Closed (a connection's port may still be in TIME_WAIT, which a listener may take): free again.
    assert listen_in_use([f"tcp/127.0.0.1:{port}"]) is None


def test_insecure_tolerates_the_exposure_and_names_it_for_the_warning() -> None:
    config = load_config()
    options = RunOptions(listen=("tcp/0.0.0.0:3474",), connect=(), record_dir=Path("."), insecure=True)
    assert "tcp/0.0.0.0:3474 is reachable" in str(tolerated_exposure(config, options))
    insecure_config = load_config(overrides={"zenoh": {"insecure": True}})
    assert tolerated_exposure(insecure_config, RunOptions(("tcp/0.0.0.0:3474",), (), Path("."))) is not None
    with pytest.raises(UsageError):
        tolerated_exposure(config, RunOptions(("tcp/0.0.0.0:3474",), (), Path(".")))


def test_the_password_stays_out_of_the_shown_and_recorded_config() -> None:
    config = load_config(overrides={"zenoh": {"auth": {"user": "r1", "password": "s3cret"}}})
    assert config.zenoh.auth.password == "s3cret"
    assert config.to_dict()["zenoh"]["auth"]["password"] == "(hidden)"
    assert "s3cret" not in repr(config)


def test_roles_become_a_default_deny_access_control_with_one_subject_per_identity() -> None:
    zenoh_config = parse_zenoh(
        {
            "listen": [],
            "connect": [],
            "tls": {"root_ca_certificate": "ca.pem", "certificate": "r.pem", "private_key": "r.key"},
            "auth": {"dictionary_file": "passwords.txt"},
            "access": {"enabled": True, "operators": ["alice"], "monitors": ["bob"], "robots": ["r7"]},
        }
    )
    from daemon.security import node_settings

    acl = node_settings(zenoh_config)["access_control"]
    assert isinstance(acl, dict)
    assert acl["default_permission"] == "deny"
    assert {"id": "monitor-bob", "cert_common_names": ["bob"], "usernames": ["bob"]} in acl["subjects"]
    policies = {p["subjects"][0]: p["rules"] for p in acl["policies"]}
    assert policies["monitor-bob"] == ["watch_in", "watch_out", "status_in", "status_out"]
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["status_in"]["key_exprs"] == ["dishbot/*/cmd/status"]
    assert rules["serve-r7"]["key_exprs"] == ["dishbot/r7/**"]  # a robot serves its own keys only


# --- over real sessions -------------------------------------------------------------------------------------


@pytest.mark.slow
def test_operator_commands_monitor_watches_and_intruders_are_refused(
    keys: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    site = keys / "site"
    config = load_config(site / "robot.toml")
    endpoint = config.zenoh.listen[0]
    alice, bob = _profile(keys, "alice"), _profile(keys, "bob")
    wrong_password = _copy(keys, tmp_path, "site", "wrong", ("password", 'password = "guess"'))
    foreign = _copy(keys, tmp_path, "foreign", "foreign")
    # alice's certificate with bob's user and password: both factors must name the same identity.
    bob_password = load_profile(Path(bob)).password
    mixed = _copy(keys, tmp_path, "site", "mixed", ("password", f'password = "{bob_password}"'))
    Path(mixed).write_text(Path(mixed).read_text().replace('user = "alice"', 'user = "bob"'))

    async def scenario() -> None:
        async with daemon(tmp_path, config, listen=config.zenoh.listen):
            code, out, _ = await cli(capsys, "--profile", alice, "status")
            assert (code, out.splitlines()[:2]) == (0, ["robot: r1", "state: idle"])
            # Refused at once by access control, and said so (not "did not answer within 30 s").
            code, out, err = await cli(capsys, "start", "--profile", bob, "--timeout", "30")
            assert (code, out) == (1, "")
            assert err == (
                f"dishbot start: robot 'r1' at {endpoint} refused start: access control does not let it "
                "through for monitor bob (a monitor may only watch and ask for status)\n"
            )
            code, out, _ = await cli(capsys, "--profile", bob, "status", "--json")
            assert code == 0
            shown = json.loads(out)
            assert shown["state"] == "idle"  # the monitor's start changed nothing
            assert shown["allowed"] == ["status"]  # what bob may send, not what the state allows
            code, out, _ = await cli(capsys, "--profile", bob, "status")
            assert "allowed: status" in out.splitlines()
            code, out, _ = await cli(capsys, "--profile", alice, "status")
            assert "allowed: status, start, estop" in out.splitlines()
            refused = (
                f"{endpoint} refused this client: the TLS handshake or the password failed (check the "
                "profile's certificate, key, CA and password)"
            )
            for who in (
                ["--connect", endpoint, "--robot", "r1"],
                ["--profile", wrong_password],
                ["--profile", foreign],
            ):
                code, _, err = await cli(capsys, "status", *who, "--timeout", "1")
                assert (code, err) == (1, f"dishbot status: {refused}\n"), who
            plain = endpoint.replace("tls/", "tcp/")
            code, _, err = await cli(capsys, "status", "--connect", plain, "--robot", "r1", "--timeout", "1")
            assert err == (
                f"dishbot status: {plain} accepts TCP but opened no Zenoh session (a TLS-only or "
                "password-protected robot? connect with its profile)\n"
            )
            code, _, err = await cli(capsys, "status", "--profile", mixed, "--timeout", "1")
            assert (code, err) == (
                1,
                f"dishbot status: no daemon answered for robot 'r1' at {endpoint} within 1 s\n",
            )
            code, out, _ = await cli(capsys, "--profile", alice, "start")
            assert (code, out.splitlines()[1]) == (0, "state: detect")
            await until_state(endpoint, "done", profile=load_profile(Path(alice)))

    asyncio.run(scenario())


@pytest.mark.slow
def test_a_payload_too_big_for_the_transport_is_dropped_and_the_daemon_goes_on(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = robot_config(ROBOT)
    assert transport_limit_bytes(config.daemon.max_command_bytes) == 64 * 1024

    async def scenario() -> None:
        async with daemon(tmp_path, config, listen=[endpoint]):
            huge = await asyncio.to_thread(
                ask, endpoint, f"dishbot/{ROBOT}/cmd/start", b"x" * 200_000, timeout_s=1.0
            )
            assert [body for where, body in huge if where != "error"] == []  # never reached the handler
            big = await asyncio.to_thread(ask, endpoint, f"dishbot/{ROBOT}/cmd/start", b"x" * 30_000)
            assert big == [
                (
                    f"dishbot/{ROBOT}/cmd/start",
                    {
                        "robot_id": ROBOT,
                        "ok": False,
                        "error": "payload of 30000 bytes is larger than the limit of 4096 bytes",
                    },
                )
            ]
            status = await asyncio.to_thread(ask, endpoint, f"dishbot/{ROBOT}/cmd/status")
            assert status[0][1]["state"] == "idle"

    asyncio.run(scenario())


@pytest.mark.slow
def test_zenoh_itself_refuses_a_client_without_a_certificate(keys: Path, tmp_path: Path) -> None:
    """Below the CLI: a bare Zenoh client session to the TLS endpoint does not open at all."""
    config = load_config(keys / "site" / "robot.toml")

    async def scenario() -> None:
        async with daemon(tmp_path, config, listen=config.zenoh.listen):
            from daemon.zenoh_session import session_config

            with pytest.raises(zenoh.ZError):
                zenoh.open(session_config(listen=[], connect=list(config.zenoh.listen), mode="client"))

    asyncio.run(scenario())


def test_a_tls_endpoint_without_tls_files_is_refused_before_starting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = [
        "run",
        "--sim",
        "--world",
        "kinematic",
        "--record-dir",
        str(tmp_path),
        "--listen",
        "tls/127.0.0.1:3474",
    ]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        "dishbot run: error: listen tls/127.0.0.1:3474 needs zenoh.tls (root_ca_certificate, certificate, "
        "private_key); `dishbot security init` writes them\n"
    )


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["--listen", "tcp/0.0.0.0:3474"], "zenoh listen tcp/0.0.0.0:3474 is reachable from other machines"),
        (["--listen", "3474"], "--listen: '3474' is not a Zenoh endpoint like tcp/127.0.0.1:3474"),
        (["--listen", "tls/127.0.0.1:3474"], "listen tls/127.0.0.1:3474 needs zenoh.tls"),
        (
            ["--config", "/nonexistent.toml"],
            "cannot read config file /nonexistent.toml: No such file or directory",
        ),
    ],
)
def test_the_router_refuses_bad_or_exposed_endpoints(
    argv: list[str], error: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["router", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"dishbot router: error: {error}")
    assert err.count("\n") == 1


@pytest.mark.slow
def test_the_router_routes_over_tls_with_roles(keys: Path, tmp_path: Path) -> None:
    """`dishbot router` as a process: a robot's daemon connects out to it, the operator reaches the robot."""
    home = tmp_path / "k"
    port = str(free_port())
    argv = ["security", "init", str(home), "--robot", ROBOT, "--address", "127.0.0.1", "--operator", "alice"]
    assert main([*argv, "--router", "127.0.0.1", "--port", port]) == 0
    # The robot listens on its own loopback port: the router has the profiles' one.
    robot_toml = home / "robot.toml"
    robot_toml.write_text(robot_toml.read_text().replace(f'listen = ["tls/127.0.0.1:{port}"]', "listen = []"))
    router = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "router", "--config", str(home / "router.toml")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=python_env(),
    )
    try:
        assert router.stdout is not None
        for line in router.stdout:
            if "router_ready" in line:
                break
        config = load_config(robot_toml)
        profile = load_profile(home / "alice.profile.toml")

        async def scenario() -> None:
            async with daemon(tmp_path, config, listen=[], connect=config.zenoh.connect):
                await until_state(profile.endpoint, "idle", profile=profile)

        asyncio.run(scenario())
    finally:
        router.terminate()
        assert router.wait(20) == 0


@pytest.mark.slow
def test_a_stolen_router_key_with_a_monitors_password_is_refused_at_the_robots_listener(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 23 item 1: the router's certificate and key, with any password from the dictionary, at the
    robot's own TLS listener. The router's certificate only serves its own listener: it opens no link."""
    home = tmp_path / "k"
    port = str(free_port())
    argv = ["security", "init", str(home), "--robot", ROBOT, "--address", "127.0.0.1", "--operator", "alice"]
    assert main([*argv, "--monitor", "bob", "--router", "127.0.0.2", "--port", port]) == 0
    config = load_config(home / "robot.toml")
    endpoint = config.zenoh.listen[0]
    bob = load_profile(home / "bob.profile.toml")
    assert [line.split(":")[0] for line in (home / "passwords.txt").read_text().splitlines()] == [
        ROBOT,
        "alice",
        "bob",
    ]  # the router opens no link, so it has no password
    uses = {
        name: x509.load_pem_x509_certificate((home / f"{name}.pem").read_bytes())
        .extensions.get_extension_for_class(x509.ExtendedKeyUsage)
        .value
        for name in ("router", ROBOT, "alice", "bob")
    }
    serve, connect = ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH
    assert {name: list(use) for name, use in uses.items()} == {
        "router": [serve],
        ROBOT: [serve, connect],
        "alice": [connect],
        "bob": [connect],
    }
    stolen = home / "thief.profile.toml"
    stolen.write_text(
        f'endpoint = "{endpoint}"\nrobot = "{ROBOT}"\n\n[tls]\nroot_ca_certificate = "ca.pem"\n'
        'certificate = "router.pem"\nprivate_key = "router.key"\n\n'
        f'[auth]\nuser = "bob"\npassword = "{bob.password}"\n'
    )
    stolen.chmod(0o600)

    async def scenario() -> None:
        async with daemon(tmp_path, config, listen=config.zenoh.listen):
            for verb in ("start", "estop"):
                code, out, err = await cli(capsys, verb, "--profile", str(stolen), "--timeout", "2")
                assert (code, out, err) == (
                    1,
                    "",
                    f"dishbot {verb}: {endpoint} refused this client: the TLS handshake or the password "
                    "failed (check the profile's certificate, key, CA and password)\n",
                )
            await until_state(endpoint, "idle", profile=load_profile(home / "alice.profile.toml"))

    asyncio.run(scenario())
