"""The Ray back end (experiment.ray_pool): ray_imap on a local 2-CPU Ray cluster."""

from __future__ import annotations

import itertools
import os
import random
import socket
import sys
import time

import pytest
import ray

from rrg_experiments.ray_pool import INSTALL_HINT, RayItemError, ray_available, ray_imap

#: The item square_or_fail refuses.
CURSED = 13


def square_or_fail(x: int) -> tuple[int, int, int, str | None]:
    """(x, x², the worker's pid, its OMP_NUM_THREADS); ValueError for CURSED."""
    if x == CURSED:
        raise ValueError(f"{x} is cursed")
    return x, x * x, os.getpid(), os.environ.get("OMP_NUM_THREADS")


def _items(n: int) -> list[int]:
    """n distinct seeded items, none of them CURSED."""
    return random.Random(0).sample([i for i in range(1000) if i != CURSED], n)


@pytest.fixture
def no_ray_session():
    """Fails a test that starts with a Ray session open; ends one a failing test left."""
    assert not ray.is_initialized(), "a Ray session was already open"
    yield
    if ray.is_initialized():
        ray.shutdown()


def test_ray_available_and_install_hint(monkeypatch):
    """ray_available() says yes here; without Ray, ray_imap says how to install it."""
    assert ray_available()
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert not ray_available()
    with pytest.raises(ImportError, match="Ray is not installed: pip install") as err:
        next(ray_imap(square_or_fail, [1]))
    assert str(err.value) == INSTALL_HINT


def test_no_items_start_nothing(no_ray_session):
    """An empty input yields nothing and opens no session."""
    assert list(ray_imap(square_or_fail, [], workers=2)) == []
    assert not ray.is_initialized()


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_every_item_once_on_two_long_lived_workers(no_ray_session, monkeypatch, caplog):
    """Each item's result exactly once, from two single-threaded worker processes, on the local
    cluster ray_imap starts (RAY_ADDRESS naming a dead one) and shuts down after it."""
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    items = _items(30)
    env = {k: os.environ.get(k) for k in ("RAY_USAGE_STATS_ENABLED", "RAY_AUTH_MODE")}
    out = list(ray_imap(square_or_fail, items, address="auto", workers=2, chunksize=3))
    assert sorted(r[0] for r in out) == sorted(items)
    assert all(r[1] == r[0] ** 2 for r in out)
    pids = {r[2] for r in out}
    assert len(pids) == 2 and os.getpid() not in pids  # one actor per worker, reused
    assert {r[3] for r in out} == {"1"}
    assert not ray.is_initialized()
    assert {k: os.environ.get(k) for k in env} == env  # the driver's environment restored
    assert f":{port} (a stale address?)" in caplog.text  # Ray names this host by its IP


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_an_item_that_raises_is_named(no_ray_session):
    """fn's error on one item surfaces as RayItemError naming it, caused by the original
    error, and the session is shut down all the same."""
    items = _items(10) + [CURSED]
    with pytest.raises(RayItemError, match=rf"fn failed on item {CURSED}: ValueError") as err:
        list(ray_imap(square_or_fail, items, address="auto", workers=2))
    assert err.value.item == CURSED
    assert isinstance(err.value.__cause__, ValueError)
    assert "is cursed" in str(err.value)
    assert not ray.is_initialized()


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_an_open_session_is_used_and_left_open(no_ray_session, monkeypatch):
    """In a session the caller opened, ray_imap runs there, and a consumer that stops early
    frees the workers but leaves the session to its owner."""
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        gen = ray_imap(square_or_fail, _items(40), address="auto", workers=2, chunksize=2)
        first = list(itertools.islice(gen, 3))
        assert len(first) == 3
        gen.close()
        assert ray.is_initialized()
        deadline = time.monotonic() + 30
        while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert ray.available_resources().get("CPU", 0) == 2  # its actors were ended
    finally:
        ray.shutdown()
