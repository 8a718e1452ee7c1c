"""Running a function over many items on forked worker processes, for the offline studies, the
table builds and the campaigns.

The workers are forked, so they inherit what this process has loaded (compiled models, caches,
the object search path). A worker that dies (killed for memory, or crashed) raises
``BrokenProcessPool`` in the caller, naming how each dead worker ended, instead of leaving it
waiting for ever, as ``multiprocessing.Pool`` does. A process that has started DDS must not
fork (its threads' locks are copied held): build before any node starts.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def fork_map(
    fn: Callable[[T], R], items: Iterable[T], workers: int, ordered: bool = True
) -> Iterator[R]:
    """``fn(item)`` for every item on ``workers`` forked processes: in the items' order, or
    (``ordered=False``) as each finishes. Stopping the iteration cancels what has not started."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"))
    try:
        futures: list[Future] = [pool.submit(fn, item) for item in items]
        if ordered:
            for f in futures:
                yield f.result()
        else:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield f.result()
    except BrokenProcessPool as exc:
        workers = list((getattr(pool, "_processes", None) or {}).values())  # the pool's own
        pool.shutdown(wait=True, cancel_futures=True)  # every worker reaped: its exit is known
        raise BrokenProcessPool(f"{exc} ({worker_deaths(workers)})") from exc
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def worker_deaths(workers: list[mp.Process]) -> str:
    """How a broken pool's workers ended: the signal that killed each (SIGKILL: often the
    kernel's out-of-memory killer; SIGSEGV: a crash in compiled code) or its exit code; the
    survivors the pool then stopped (SIGTERM) are counted apart."""
    deaths, stopped = [], 0
    for process in workers:
        code = process.exitcode
        if code == -signal.SIGTERM:
            stopped += 1
        elif code is not None and code != 0:
            how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
            deaths.append(f"worker {process.pid} {how}")
    if stopped:
        deaths.append(f"{stopped} more stopped by the pool")
    return "; ".join(deaths) or "no worker exit recorded"
