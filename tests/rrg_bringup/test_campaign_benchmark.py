"""rrg-bench campaign's split of a profile into parts: own time goes to the part of the code it
is spent in, and time in numpy or the standard library to the parts that called it."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from rrg_bringup.benchmarks.campaign_benchmark import OTHER, part_of, split_by_part

SENSING = ("/x/rrg_sim/physics/sensing.py", 10, "fired_now")
SEARCH = ("/x/rrg_planner/search.py", 20, "expand")
REDUCE = ("~", 0, "<method 'reduce' of 'numpy.ufunc' objects>")
NUMPY_MAX = ("/x/site-packages/numpy/_core/_methods.py", 39, "_amax")
STEP = ("~", 0, "<built-in method mujoco._functions.mj_step>")
ORPHAN = ("/x/lib/python3.11/threading.py", 5, "run")


def test_parts_are_found_by_the_code_they_are_spent_in():
    assert part_of(STEP) == "physics steps"
    assert part_of(SENSING) == "sensors and guards"
    assert part_of(SEARCH) == "forward search"
    assert part_of(REDUCE) is None and part_of(NUMPY_MAX) is None


def test_numpy_time_is_charged_to_its_callers_in_proportion():
    # (cc, nc, tottime, cumtime, callers: {caller: (cc, nc, tt, cumtime spent from it)})
    stats = {
        SENSING: (1, 1, 1.0, 3.0, {}),
        SEARCH: (1, 1, 2.0, 5.0, {}),
        STEP: (1, 1, 4.0, 4.0, {}),
        # _amax is called by the sensors (1 s) and the search (3 s); reduce only by _amax
        NUMPY_MAX: (1, 1, 0.4, 4.0, {SENSING: (1, 1, 0.1, 1.0), SEARCH: (1, 1, 0.3, 3.0)}),
        REDUCE: (1, 1, 3.6, 3.6, {NUMPY_MAX: (1, 1, 3.6, 3.6)}),
        ORPHAN: (1, 1, 0.5, 0.5, {}),
    }
    parts = split_by_part(SimpleNamespace(stats=stats))
    assert parts["physics steps"] == pytest.approx(4.0)
    assert parts["sensors and guards"] == pytest.approx(1.0 + 0.25 * 4.0)
    assert parts["forward search"] == pytest.approx(2.0 + 0.75 * 4.0)
    assert parts[OTHER] == pytest.approx(0.5)  # no caller to charge
    assert sum(parts.values()) == pytest.approx(sum(v[2] for v in stats.values()))
