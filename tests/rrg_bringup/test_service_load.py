"""The planner's select_action under load from several client processes on a busy machine
(``rrg-bench service``): every call is answered, and the planner sends every response. Speed is
printed by the benchmark, never asserted here."""

from __future__ import annotations

import json

import pytest

from rrg_bringup.benchmarks.service_benchmark import bench_service

pytestmark = pytest.mark.slow  # node and client processes


def test_every_call_of_several_client_processes_is_answered_on_a_busy_machine(ros_domain, capsys):
    args = ["--object", "box", "--level", "high", "--clients", "4", "--calls", "25"]
    args += ["--busy", "1", "--call-timeout", "60", "--domain-id", str(ros_domain), "--json"]
    assert bench_service(args) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert not figures["client_failures"] and figures["calls"] == 100, figures
    assert figures["unanswered"] == 0 and figures["answered"] == 100, figures
    assert figures["planner_send_failures"] == 0, figures
    assert 0.0 < figures["planning_p50_ms"] <= figures["latency_p50_ms"], figures
