"""What the emulated drivers' tests (rrg_fake_hw/test_fake_hw.py) and the bridge's wam_node
tests (rrg_hw_bridge/test_hw_wam_node.py) share: the box's pose, the Net F/T boxes' hosts and a
UDP port free on all of them."""

from __future__ import annotations

import socket

import numpy as np

BOX_POSE = np.array([0.625, 0.004, 0.05])
HOSTS = ["127.0.0.2", "127.0.0.3", "127.0.0.4"]


def free_udp_port(hosts: list[str]) -> int:
    """A UDP port free on every host."""
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((hosts[0], 0))
            port = s.getsockname()[1]
        try:
            for h in hosts:
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    s.bind((h, port))
            return port
        except OSError:
            continue
    raise RuntimeError("no free UDP port")
