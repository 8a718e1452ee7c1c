"""The ROS tests' helpers (ros_testing): a DDS domain id is held by one test process at a time,
and the test-side client leaves this process's environment as it found it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from ros_testing import RosClient, exclusive_domain_id, ros_env

TESTS = Path(__file__).resolve().parents[1]  # where ros_testing.py is
HOLD = """
import sys
from ros_testing import exclusive_domain_id
with exclusive_domain_id() as domain_id:
    print(domain_id, flush=True)
    sys.stdin.read()  # held until the test closes our stdin
"""


def test_a_domain_id_is_held_by_one_test_process_at_a_time():
    with exclusive_domain_id() as mine:
        other = subprocess.Popen(
            [sys.executable, "-c", HOLD],
            cwd=TESTS,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            theirs = int(other.stdout.readline())
            with exclusive_domain_id() as third:  # a second holder in this process too
                assert len({mine, theirs, third}) == 3
                assert all(1 <= d <= 101 for d in (mine, theirs, third))
        finally:
            other.communicate("", timeout=30)
        assert other.returncode == 0


def test_the_client_joins_its_domain_and_leaves_the_environment_as_it_was(ros_domain):
    before = dict(os.environ)
    client = RosClient(ros_env(ros_domain), "env_check")
    try:
        assert client.context.get_domain_id() == ros_domain
        assert dict(os.environ) == before
    finally:
        client.close()
    assert dict(os.environ) == before
