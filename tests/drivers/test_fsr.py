"""The FSR line protocol, and the asyncio reader against the simulated Arduino: in-process on a simulated
clock, and on a pty on the wall clock where the transport itself is what is tested."""

from __future__ import annotations

import threading
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.clock import RealClock, SimulatedClock
from drivers.dynamixel import DeviceEvent
from drivers.errors import SensorFault
from drivers.fsr import FsrReader
from drivers.fsr import protocol as fp
from drivers.interfaces import Clock, ForceSensor
from drivers.sim.fsr import FsrSimulator
from tests.fakes.devices import TRANSPORTS, opener, run_on, serving


class Pad:
    """The force the world puts on the pad, settable from the test."""

    def __init__(self, force_n: float = 0.0) -> None:
        self.force_n = force_n
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return self.force_n

    def set(self, force_n: float) -> None:
        with self._lock:
            self.force_n = force_n


async def until(clock: Clock, predicate: object, timeout_s: float = 2.0) -> None:
    """Poll ``predicate`` every 10 ms of ``clock``'s time, for at most ``timeout_s`` of it."""
    deadline = clock.monotonic() + timeout_s
    while not predicate():  # type: ignore[operator]
        if clock.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        await clock.sleep(0.01)


def reader_on(sim: FsrSimulator, clock: Clock, **kw: Any) -> FsrReader:
    return FsrReader(sim.device_path, clock=clock, open_serial=opener(sim), **kw)


def test_sample_line_has_the_sketch_format_and_xor_checksum() -> None:
    assert fp.sample_line(7, 512) == b"$FSR,7,512*46\r\n"
    assert fp.parse_line(b"$FSR,7,512*46") == fp.Sample(7, 512)
    assert fp.parse_line(
        b"$VER,dishbot_fsr,1*" + f"{fp.checksum('VER,dishbot_fsr,1'):02X}".encode()
    ) == fp.Version("dishbot_fsr", "1")


@pytest.mark.parametrize(
    "line",
    [
        b"$FSR,7,512*47",
        b"$FSR,7,1024*" + f"{fp.checksum('FSR,7,1024'):02X}".encode(),
        b"FSR,7,512*7B",
        b"$FSR,7*00",
        b"$FSR,-1,5*" + f"{fp.checksum('FSR,-1,5'):02X}".encode(),
        b"\xff\xfe",
        b"",
    ],
)
def test_invalid_lines_are_rejected(line: bytes) -> None:
    assert fp.parse_line(line) is None


def test_force_model_round_trips_within_one_adc_count() -> None:
    for force in (0.5, 2.0, 10.0, 20.0):
        raw = fp.raw_from_force(force)
        assert fp.raw_from_force(fp.force_from_raw(raw)) == raw
        assert fp.force_from_raw(raw) == pytest.approx(force, rel=0.05)
    assert fp.force_from_raw(0) == 0.0


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=80))
def test_parse_line_never_crashes_and_only_accepts_checksummed_lines(line: bytes) -> None:
    parsed = fp.parse_line(line)
    if isinstance(parsed, fp.Sample):
        assert fp.sample_line(parsed.seq, parsed.raw).strip() == line.strip()


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 65535), st.integers(0, 1023), st.integers(0, 14), st.integers(1, 255))
def test_a_corrupted_sample_line_is_never_accepted(seq: int, raw: int, index: int, flip: int) -> None:
    line = bytearray(fp.sample_line(seq, raw).strip())
    index %= len(line)
    line[index] ^= flip
    parsed = fp.parse_line(bytes(line))
    assert parsed is None or (
        parsed == fp.Sample(seq, raw) and bytes(line).strip() == fp.sample_line(seq, raw).strip()
    )


def test_reader_rejects_a_release_level_above_the_threshold() -> None:
    with pytest.raises(ValueError, match=r"^fsr\.release_n 3\.0 must be in \[0, threshold_n=2\.0\)$"):
        FsrReader("/dev/null", clock=RealClock(), threshold_n=2.0, release_n=3.0)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_reader_detects_a_grasp_after_the_debounce_and_releases_with_hysteresis(transport: str) -> None:
    async def body(clock: Clock) -> None:
        pad = Pad()
        with serving(FsrSimulator(pad), transport, clock) as sim:
            async with reader_on(sim, clock, threshold_n=2.0, release_n=1.0, debounce_s=0.05) as reader:
                assert isinstance(reader, ForceSensor)
                assert reader.firmware_version == "1"
                await until(clock, lambda: reader.latest() is not None)
                assert not reader.holding()
                pad.set(3.0)
                await until(clock, reader.holding)
                pad.set(1.5)  # between release and threshold: still holding
                await clock.sleep(0.15)
                assert reader.holding()
                pad.set(0.2)
                await until(clock, lambda: not reader.holding())
                assert reader.counters.bad_lines == 0

    run_on(transport, body)


def test_on_a_simulated_clock_a_grasp_is_believed_after_the_same_simulated_time_every_run() -> None:
    def press_to_holding() -> float:
        clock = SimulatedClock()

        async def body() -> float:
            pad = Pad()
            with serving(FsrSimulator(pad), "inprocess", clock) as sim:
                async with reader_on(sim, clock, threshold_n=2.0, debounce_s=0.05) as reader:
                    await until(clock, lambda: reader.latest() is not None)
                    pad.set(3.0)
                    pressed = clock.monotonic()
                    await until(clock, reader.holding)
                    return clock.monotonic() - pressed

        return clock.run(body())

    first, second = press_to_holding(), press_to_holding()
    assert first == second
    # Two 10 ms samples until the median of three turns, the 50 ms debounce, then the 10 ms poll.
    assert 0.06 <= first <= 0.09


def test_a_drop_while_carrying_is_reported_once() -> None:
    async def body(clock: Clock) -> list[DeviceEvent]:
        pad = Pad(5.0)
        events: list[DeviceEvent] = []
        with serving(FsrSimulator(pad), "inprocess", clock) as sim:
            async with reader_on(sim, clock, on_event=events.append) as reader:
                await until(clock, reader.holding)
                reader.set_carrying(True)
                sim.drop_force()
                await until(clock, lambda: reader.dropped)
                await clock.sleep(0.05)
        return events

    assert [e.kind for e in run_on("inprocess", body)] == ["mug_dropped"]


def test_a_single_sample_spike_neither_grasps_nor_drops() -> None:
    async def body(clock: Clock) -> None:
        pad = Pad(0.0)
        with serving(FsrSimulator(pad), "inprocess", clock) as sim:
            async with reader_on(sim, clock, debounce_s=0.0) as reader:
                await until(clock, lambda: reader.latest() is not None)
                sim.spike(25.0)
                await until(clock, lambda: reader.counters.spikes >= 1)
                assert not reader.holding()
                pad.set(5.0)
                await until(clock, reader.holding)
                reader.set_carrying(True)
                sim.spike(0.0)
                spikes = reader.counters.spikes
                await until(clock, lambda: reader.counters.spikes > spikes)
                assert reader.holding()
                assert not reader.dropped

    run_on("inprocess", body)


def test_garbage_torn_lines_and_bad_checksums_are_skipped() -> None:
    async def body(clock: Clock) -> None:
        pad = Pad(3.0)
        with serving(FsrSimulator(pad), "inprocess", clock) as sim:
            async with reader_on(sim, clock) as reader:
                await until(clock, reader.holding)
                sim.inject_garbage(b"\x00\xff$FSR,1,2*\r\nnoise\n")
                sim.bad_checksums(3)
                sim.tear_lines(2)
                await until(clock, lambda: reader.counters.bad_lines >= 5)
                await clock.sleep(0.05)
                assert reader.holding()
                latest = reader.latest()
                assert latest is not None
                assert latest.force_n == pytest.approx(3.0, rel=0.05)
                assert reader.counters.lost_samples >= 3  # the bad and torn lines are gaps in the sequence

    run_on("inprocess", body)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_unplug_is_reported_and_the_reader_reconnects_on_replug(transport: str) -> None:
    async def body(clock: Clock) -> None:
        pad = Pad(3.0)
        events: list[DeviceEvent] = []
        with serving(FsrSimulator(pad), transport, clock) as sim:
            async with reader_on(sim, clock, on_event=events.append, reconnect_period_s=0.05) as reader:
                await until(clock, reader.holding)
                sim.unplug()
                await until(clock, lambda: [e.kind for e in events] == ["fsr_lost"])
                with pytest.raises(
                    SensorFault, match=rf"^the FSR Arduino on {sim.device_path} is unplugged; reconnecting$"
                ):
                    reader.check()
                sim.replug()
                await until(clock, lambda: "fsr_restored" in [e.kind for e in events])
                reader.check()
                assert reader.counters.reconnects == 1

    run_on(transport, body)


def test_a_silent_stream_is_reported_stale_and_check_raises() -> None:
    async def body(clock: Clock) -> None:
        pad = Pad(0.0)
        events: list[DeviceEvent] = []
        with serving(FsrSimulator(pad), "inprocess", clock) as sim:
            async with reader_on(sim, clock, on_event=events.append, stale_after_s=0.1) as reader:
                await until(clock, lambda: reader.latest() is not None)
                sim.silence()
                await until(clock, lambda: [e.kind for e in events] == ["fsr_stale"])
                with pytest.raises(
                    SensorFault, match=r"^no valid FSR sample from .* \(the last one is .* s old\); check"
                ):
                    reader.check()
                sim.silence(on=False)
                await until(clock, lambda: [e.kind for e in events] == ["fsr_stale", "fsr_restored"])

    run_on("inprocess", body)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_port_without_the_sketch_fails_to_start_with_a_clear_error(transport: str) -> None:
    async def body(clock: Clock) -> None:
        pad = Pad(0.0)
        with serving(FsrSimulator(pad, version=""), transport, clock) as sim:  # no version: not our sketch
            sim.silence()
            with pytest.raises(SensorFault) as raised:
                async with reader_on(sim, clock, version_timeout_s=0.2):
                    pass
            assert str(raised.value) == (
                f"no dishbot_fsr sketch answered on {sim.device_path} within 0.2 s; "
                "flash drivers/fsr/arduino/dishbot_fsr.ino and check the baud rate"
            )

    run_on(transport, body)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.binary(max_size=30), st.integers(0, 1023)), max_size=20), st.integers(1, 9))
def test_the_reader_only_ever_accepts_samples_that_were_sent(
    chunks: list[tuple[bytes, int]], cut: int
) -> None:
    reader = FsrReader("/dev/null", clock=RealClock())
    sent: dict[int, int] = {}
    stream = b""
    for seq, (noise, raw) in enumerate(chunks):
        sent[seq] = raw
        stream += noise + fp.sample_line(seq, raw)
    accepted: list[tuple[int, int]] = []
    for i in range(0, len(stream), cut):
        reader._feed(stream[i : i + cut])
        latest = reader.latest()
        if latest is not None and (not accepted or accepted[-1][0] != latest.seq):
            accepted.append((latest.seq, latest.raw))
    assert all(sent.get(seq) == raw for seq, raw in accepted)
