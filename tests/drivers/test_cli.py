"""`dishbot servo|fsr|sim` against the simulated devices, and their one-line errors on bad input."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading

import pytest

from cli.commands import servo as servo_commands
from cli.main import main
from drivers.sim import FsrSimulator, ServoChainSimulator, default_chain


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Exit code, stdout, and the last stderr line (structured logs go to stderr before it)."""
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, (err.splitlines() or [""])[-1]


@pytest.mark.slow
@pytest.mark.xdist_group("realtime-pty")  # its pseudo-terminal bus answers in real time: one at a time
def test_sim_bus_prints_its_device_path_on_the_first_line_and_serves_the_thesis_chain(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # The scan waits 10 ms at each id (253 ids in 2.5 s); the child process answering on the pty is
    # sometimes 100-250 ms late on a loaded test machine (load 7), and a missed ping is a missing servo.
    # What this test checks is the chain the simulator serves, so its scan waits longer.
    monkeypatch.setattr(servo_commands, "_SCAN_TIMEOUT_S", 0.5)
    child = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "sim", "bus"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        path = child.stdout.readline().strip()
        code, out, _ = run(["servo", "scan", "--port", path, "--max-id", "8", "--json"], capsys)
        assert code == 0
        servos = json.loads(out)["servos"]
        assert [(s["id"], s["model"]) for s in servos] == list(default_chain())
    finally:
        child.send_signal(signal.SIGINT)  # Ctrl-C ends it cleanly
        assert child.wait(timeout=10) == 0


def test_servo_set_id_moves_a_servo_and_refuses_a_taken_id(capsys: pytest.CaptureFixture[str]) -> None:
    with ServoChainSimulator([(1, "MX-28T"), (2, "AX-12A")]) as sim:
        code, out, _ = run(
            ["servo", "set-id", "--port", sim.device_path, "--id", "1", "--new-id", "7"], capsys
        )
        assert (code, out) == (0, "servo 1 (MX-28T) is now id 7\n")
        assert sim.servo(7).spec.name == "MX-28T"
        code, _, err = run(
            ["servo", "set-id", "--port", sim.device_path, "--id", "7", "--new-id", "2"], capsys
        )
        assert code == 2
        assert err == "dishbot servo: error: id 2 is already used by a AX-12A; pick a free id"


def test_servo_set_baud_switches_the_servo_and_the_scan_finds_it_there(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with ServoChainSimulator([(3, "AX-12A")]) as sim:
        code, out, _ = run(
            ["servo", "set-baud", "--port", sim.device_path, "--id", "3", "--new-baud", "57600"], capsys
        )
        assert (code, out) == (0, "servo 3 (AX-12A) now talks at 57600 bps\n")
        code, out, _ = run(
            ["servo", "scan", "--port", sim.device_path, "--max-id", "5", "--all-bauds", "--json"], capsys
        )
        assert [(s["id"], s["baud"]) for s in json.loads(out)["servos"]] == [(3, 57600)]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["servo", "set-id", "--id", "1", "--new-id", "300"], "--new-id 300 is outside 0..252"),
        (
            ["servo", "set-id", "--id", "1", "--new-id", "1"],
            "--new-id 1 is the servo's present id; nothing to change",
        ),
        (
            ["servo", "set-id", "--id", "9", "--new-id", "4"],
            "no servo answers at id 9 on PORT at 1000000 bps; run `dishbot servo scan --all-bauds`",
        ),
        (
            ["servo", "set-baud", "--id", "1", "--new-baud", "12345"],
            "baud rate 12345 is not settable on Protocol "
            "1.0; use one of 9600, 19200, 57600, 115200, 500000, 1000000",
        ),
        (["servo", "scan", "--protocol", "3"], "bus.protocol must be 1 or 2, got 3"),
        (
            ["servo", "scan", "--baud", "1234"],
            "bus.baudrate 1234 is not a Protocol 1.0 rate; use 9600, 19200, 57600, 115200, 500000, 1000000",
        ),
        (
            ["sim", "bus", "--servos", "1:MX-99"],
            "--servos entry '1:MX-99': unknown Dynamixel model 'MX-99'; "
            "supported: AX-12A, MX-28T, MX-64T, MX-106T, XL430-W250, XM430-W350, XL330-M288",
        ),
        (
            ["sim", "bus", "--servos", "x:AX-12A"],
            "--servos entry 'x:AX-12A': the id must be a number in 0..252",
        ),
        (["sim", "bus", "--servos", "1:AX-12A,1:AX-12A"], "--servos lists an id twice"),
        (["fsr", "calibrate", "--mass-kg", "0"], "--mass-kg 0.0 must be in (0, 5] kg"),
    ],
)
def test_bad_input_gets_a_one_line_error_and_exit_2(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with ServoChainSimulator([(1, "MX-28T")]) as sim:
        port = sim.device_path
        if argv[0] != "sim":
            argv = [*argv, "--port", port]
        code, out, err = run(argv, capsys)
        assert (code, out) == (2, "")
        assert err == f"dishbot {argv[0]}: error: {message.replace('PORT', port)}"
        assert sim.servo(1).get("id") == 1


def test_servo_commands_name_a_missing_port(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["servo", "scan", "--port", "/dev/does-not-exist"], capsys)
    assert code == 2
    assert err.startswith("dishbot servo: error: cannot open servo bus /dev/does-not-exist: ")
    assert err.endswith("; check the USB cable and the udev rule")


def test_fsr_calibrate_prints_the_gain_that_reads_the_weight_in_newtons(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    force = {"n": 0.0}
    lock = threading.Lock()

    def pad() -> float:
        with lock:
            return force["n"]

    def prompt(text: str) -> str:
        with lock:
            force["n"] = (
                0.0 if "Take everything off" in text else 0.2 * 9.81 * 1.25
            )  # this pad reads 25 % high
        return ""

    monkeypatch.setattr("builtins.input", prompt)
    with FsrSimulator(pad) as sim:
        code, out, _ = run(
            ["fsr", "calibrate", "--port", sim.device_path, "--mass-kg", "0.2", "--seconds", "0.3", "--json"],
            capsys,
        )
    assert code == 0
    result = json.loads(out)
    assert result["gain"] == pytest.approx(0.8, rel=0.03)
    assert result["loaded_n"] == pytest.approx(0.2 * 9.81, rel=0.001)
    assert result["release_n"] < result["threshold_n"] < result["loaded_n"]
