"""tests/fakes/ports.py: a block of ports below the ephemeral range per xdist worker, none reused soon."""

from __future__ import annotations

import socket

from tests.fakes.ports import BLOCK, FIRST_PORT, block, free_port, is_free


def test_each_worker_has_its_own_block_below_the_ephemeral_range() -> None:
    blocks = [block(f"gw{i}") for i in range(11)] + [block(None)]
    assert len({b.start for b in blocks}) == 12  # eleven workers and a serial run, none sharing
    assert all(b.start >= FIRST_PORT and len(b) == BLOCK for b in blocks)
    assert max(b.stop for b in blocks) <= 32_768  # Linux's ephemeral range starts there by default
    assert block("gw11") == block("gw0")  # more workers than blocks share, in turn
    assert block("master") == block(None)


def test_free_ports_are_never_given_twice_and_are_free() -> None:
    ports = [free_port() for _ in range(50)]
    assert len(set(ports)) == 50
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", port))  # free: it binds


def test_a_port_something_listens_on_is_not_free() -> None:
    port = free_port()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        assert not is_free(port)
    assert is_free(port)


def test_a_process_may_ask_for_more_ports_than_its_block_holds() -> None:
    """A serial run (one process, one block) starts more daemons than a block has ports: a port comes back
    only after half a block of others."""
    ports = [free_port() for _ in range(BLOCK + 200)]
    assert len(ports) == BLOCK + 200
    window = BLOCK // 2
    assert all(len(set(ports[i : i + window])) == window for i in range(0, len(ports) - window, 97))
