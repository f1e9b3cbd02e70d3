"""Host names and addresses, for what listens or connects on the network (Zenoh endpoints, the Foxglove
server)."""

from __future__ import annotations

import ipaddress


def is_loopback(host: str) -> bool:
    """Whether only this machine can reach ``host`` (a name or an address without brackets): 127.0.0.0/8,
    ::1 or localhost."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
