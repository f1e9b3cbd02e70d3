"""Replaying recorded sessions: ``dishbot replay`` re-runs a session through the daemon on simulated time,
serving the recorded driver-boundary inputs for as long as the daemon does what it did, with faults
injected at the device boundary or in the simulated world (``daemon.replay.faults``).

``daemon.replay.streams`` is the lower layer: a recording's inputs as timed streams, rewritten by a
``FaultPlan`` and served back by stand-in drivers (for tests of one driver or one rule).
"""

from daemon.replay.faults import (
    FAULT_KINDS,
    FaultInjector,
    FaultSpec,
    dump_faults,
    load_fault_file,
    parse_faults,
)
from daemon.replay.streams import (
    DEFAULT_STREAMS,
    Cut,
    Delay,
    Drop,
    Fault,
    FaultPlan,
    Noise,
    ReplayClock,
    ReplayForceSensor,
    ReplayMugObserver,
    Spike,
    TimedInput,
    Timeline,
    decode_force,
    decode_joints,
    decode_observation,
)

__all__ = [
    "DEFAULT_STREAMS",
    "FAULT_KINDS",
    "Cut",
    "Delay",
    "Drop",
    "Fault",
    "FaultInjector",
    "FaultPlan",
    "FaultSpec",
    "Noise",
    "ReplayClock",
    "ReplayForceSensor",
    "ReplayMugObserver",
    "Spike",
    "TimedInput",
    "Timeline",
    "decode_force",
    "decode_joints",
    "decode_observation",
    "dump_faults",
    "load_fault_file",
    "parse_faults",
]
