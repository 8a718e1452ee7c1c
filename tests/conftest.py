"""Fixtures shared by the test modules, and their order."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

#: Packages whose sessions leave threads running in the process after they end (DDS's, Ray's).
THREADED_PACKAGES = {"rclpy", "ray"}


@functools.cache
def leaves_threads(path: Path) -> bool:
    """Whether a test module may start rclpy or Ray in the test process itself: it imports
    them or the test-side RosClient, at its top or in a test."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            modules = [node.module or ""] + [a.name for a in node.names]
        else:
            continue
        if any(m.split(".")[0] in THREADED_PACKAGES or m == "RosClient" for m in modules):
            return True
    return False


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules that start rclpy or Ray in this process run last: their threads outlive their
    sessions, and a process forked while they run (the workers of the table builds, studies and
    campaigns: rrg_common.parallel) can inherit their locks held, and hang or crash."""
    items.sort(key=lambda item: leaves_threads(item.path))


@pytest.fixture(scope="module")
def ros_domain() -> int:
    """A DDS domain id (1-101) that no other test process on this machine holds, for the module
    (ros_testing.exclusive_domain_id)."""
    from ros_testing import exclusive_domain_id  # rclpy is imported only by the ROS tests

    with exclusive_domain_id() as domain_id:
        yield domain_id
