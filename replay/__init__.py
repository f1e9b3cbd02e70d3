"""Replaying recorded sessions: ``dishbot replay`` re-runs a session through the daemon on simulated time,
serving the recorded driver-boundary inputs for as long as the daemon does what it did, with faults
injected at the device boundary or in the simulated world (``replay.faults``).
"""
