"""rrg_common.parallel.fork_map: results in order or as finished, and a worker that dies raises in
the caller instead of leaving it waiting."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures.process import BrokenProcessPool

import pytest

from rrg_common.parallel import fork_map

INHERITED = {"scale": 3}  # set before the fork: the workers see it without pickling


def scaled(x: int) -> int:
    time.sleep(0.01 * (x % 3))
    return INHERITED["scale"] * x


def dies_on_seven(x: int) -> int:
    if x == 7:
        os.kill(os.getpid(), signal.SIGKILL)
    return x


def test_ordered_results_come_in_the_items_order_and_see_the_parents_memory():
    INHERITED["scale"] = 5
    try:
        assert list(fork_map(scaled, range(20), workers=2)) == [5 * x for x in range(20)]
    finally:
        INHERITED["scale"] = 3


def test_unordered_results_cover_every_item_once():
    assert sorted(fork_map(scaled, range(20), workers=2, ordered=False)) == [
        3 * x for x in range(20)
    ]


@pytest.mark.parametrize("ordered", [True, False])
def test_a_killed_worker_raises_instead_of_hanging(ordered):
    t0 = time.monotonic()
    with pytest.raises(BrokenProcessPool, match=r"worker \d+ killed by SIGKILL"):
        list(fork_map(dies_on_seven, range(40), workers=2, ordered=ordered))
    assert time.monotonic() - t0 < 30.0  # multiprocessing.Pool would wait for ever


def logged(item: tuple[str, int]) -> int:
    path, x = item
    with open(path, "a") as f:
        f.write(f"{x}\n")
    time.sleep(0.01)
    return x


def test_leaving_the_iteration_early_cancels_the_rest_and_joins_the_workers(tmp_path):
    log = tmp_path / "ran.txt"
    results = fork_map(logged, [(str(log), x) for x in range(1000)], workers=2)
    assert next(results) == 0
    results.close()
    assert not multiprocessing.active_children()
    assert len(log.read_text().split()) < 50  # only the few already handed to a worker ran
