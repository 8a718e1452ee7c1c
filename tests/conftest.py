"""Fixtures shared by the test modules."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def ros_domain() -> int:
    """A DDS domain id (1-101) that no other test process on this machine holds, for the module
    (ros_testing.exclusive_domain_id)."""
    from ros_testing import exclusive_domain_id  # rclpy is imported only by the ROS tests

    with exclusive_domain_id() as domain_id:
        yield domain_id
