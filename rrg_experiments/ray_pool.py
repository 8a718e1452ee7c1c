"""An optional Ray back end for the experiment trials: ``ray_imap``, a cluster-wide
``imap_unordered``.

Each Ray worker is a long-lived actor that calls ``fn`` on chunks of items, so the per-process
caches in ``trials`` (the loaded models and worlds) serve every trial it runs, as in the fork
pool. Results come back verbatim (unordered). The workers run BLAS single-threaded, so a result
is the one a process with one BLAS thread computes (some of rrg's sums differ in the last bit
with more threads).

``address``: "auto" connects to the cluster that RAY_ADDRESS or ``ray start`` on this machine
names, or else starts a local one (loopback only, no dashboard, no usage reports) for the
call; "host:6379" joins a cluster as a driver, "ray://host:10001" through the Ray client
(``pip install 'ray[client]'``). Only a session this module opened is shut down after it.
A remote cluster needs rrg installed (``pip install -e .``) on every node, with its table caches.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import socket
import sys
import traceback
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

log = logging.getLogger(__name__)

#: The checkout holding rrg_planner, rrg_sim and rrg_estimator (on the workers' PYTHONPATH).
ROOT = Path(__file__).resolve().parents[1]

INSTALL_HINT = (
    "Ray is not installed: pip install 'ray>=2.9' (or pip install -e '.[ray]' in the rrg "
    "checkout, which scripts/setup.sh does)"
)

#: Installed packages' import roots, which the workers have already.
SITE_DIRS = ("site-packages", "dist-packages")

#: One BLAS / OpenMP thread per worker: the workers are the parallelism.
THREAD_ENV = {
    v: "1"
    for v in (
        "OMP_NUM_THREADS",
        "OPENBLAS_NUM_THREADS",
        "MKL_NUM_THREADS",
        "VECLIB_MAXIMUM_THREADS",
        "NUMEXPR_NUM_THREADS",
    )
}

#: The driver's environment while connected, inherited by a local cluster started here: no
#: usage reports (a sandbox has no network for them).
RAY_ENV = {"RAY_USAGE_STATS_ENABLED": "0"}
#: Variables ray.init itself sets (token authentication), restored after the session too.
RAY_SETS = ("RAY_AUTH_MODE",)

#: Ray's notice, on each connection, that token authentication is on (its default since 2.5x;
#: a local cluster started here listens on the loopback only), kept out of the output.
AUTH_NOTICE_LOGGER = "ray._private.authentication.authentication_token_setup"

#: Object store of a local cluster (bytes): results are small records.
LOCAL_OBJECT_STORE = 256 * 1024**2

#: Chunks queued per actor beyond the one it runs (backpressure: at most 1 + this in flight).
QUEUED_PER_ACTOR = 1


class RayItemError(RuntimeError):
    """fn raised on a Ray worker for ``item`` (the remote error's type, message and traceback
    in the message; the error itself as ``__cause__`` when it could be unpickled)."""

    def __init__(self, item: Any, message: str):
        super().__init__(message)
        self.item = item


def ray_available() -> bool:
    """Whether Ray can be imported here."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def _import_ray():
    """The ray module, or an ImportError that says how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise ImportError(INSTALL_HINT) from exc
    return ray


class _Runner:
    """Calls fn on chunks of items in one long-lived worker process."""

    def __init__(self, fn: Callable[[Any], Any]):
        self.fn = fn

    def run(self, chunk: list) -> list[tuple[bool, Any]]:
        """(True, fn(item)) per item, or (False, (traceback, pickled error or None)) for one
        that raised; the rest of the chunk still runs."""
        from ray import cloudpickle

        out = []
        for item in chunk:
            try:
                out.append((True, self.fn(item)))
            except Exception as exc:
                try:
                    blob = cloudpickle.dumps(exc)
                except Exception:
                    blob = None
                out.append((False, (traceback.format_exc(), blob)))
        return out


def _import_root(fn: Callable) -> Path | None:
    """The sys.path entry fn's module was imported from (None for __main__ or no file)."""
    name = getattr(fn, "__module__", None)
    mod = sys.modules.get(name) if name else None
    path = getattr(mod, "__file__", None)
    if not path or name == "__main__":
        return None
    depth = name.count(".") + (1 if Path(path).stem == "__init__" else 0)
    return Path(path).resolve().parents[depth]


def _runtime_env(fn: Callable, local: bool) -> dict:
    """The actors' runtime environment: single-threaded BLAS; on a cluster on this machine, the
    checkout (and fn's own import root, e.g. tests/) on PYTHONPATH."""
    env = dict(THREAD_ENV)
    if local:
        roots = [str(ROOT)]
        extra = _import_root(fn)
        if extra is not None and extra.name not in SITE_DIRS and str(extra) not in roots:
            roots.append(str(extra))
        if os.environ.get("PYTHONPATH"):  # the driver's, which a local cluster's workers share
            roots.append(os.environ["PYTHONPATH"])
        env["PYTHONPATH"] = os.pathsep.join(roots)
    return {"env_vars": env}


@contextlib.contextmanager
def _quiet(logger: str) -> Iterator[None]:
    """The named logger at ERROR level for the block."""
    lg = logging.getLogger(logger)
    saved = lg.level
    lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        lg.setLevel(saved)


@contextlib.contextmanager
def _environ(values: dict[str, str], restore: Iterable[str] = ()) -> Iterator[None]:
    """os.environ with values set (only the unset ones); they and restore restored on exit."""
    saved = {k: os.environ.get(k) for k in [*values, *restore]}
    for k, v in values.items():
        os.environ.setdefault(k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _answers(host: str, port: int, timeout: float = 2.0) -> bool:
    """Whether something accepts TCP connections at host:port."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def _find_cluster() -> str | None:
    """The running cluster "auto" names (RAY_ADDRESS, the last ``ray start`` here, or a live
    one), or None: none, or a stale address that nothing answers at (from a ``ray start``
    that was killed, which ray.init would wait minutes on)."""
    if "://" in os.environ.get("RAY_ADDRESS", ""):
        return "auto"  # the Ray client: ray.init resolves it
    try:
        from ray._private.services import canonicalize_bootstrap_address

        addr = canonicalize_bootstrap_address("auto")
    except ConnectionError:
        return None
    except Exception:  # a Ray whose private helper differs: ray.init resolves "auto"
        return "auto"
    if addr is None:
        return None
    host, _, port = addr.rpartition(":")
    if port.isdigit() and not _answers(host.strip("[]"), int(port)):
        log.warning("ray_imap: no Ray cluster answers at %s (a stale address?)", addr)
        return None
    return addr


def _connect(ray, address: str, workers: int | None, stack: contextlib.ExitStack) -> bool:
    """Connect to address ("auto": a running cluster, else start a local one with `workers`
    CPUs); True when this call started the session (stack then ends it)."""
    if ray.is_initialized():
        log.info("ray_imap: using the Ray session already open in this process")
        return False
    stack.enter_context(_environ(RAY_ENV, RAY_SETS))  # restored after the shutdown below
    stack.enter_context(_quiet(AUTH_NOTICE_LOGGER))
    quiet = dict(logging_level=logging.WARNING, log_to_driver=True)
    target = _find_cluster() if address == "auto" else address
    try:
        if target is None:
            raise ConnectionError("no running Ray cluster")
        ray.init(address=target, **quiet)
    except ConnectionError:
        if address != "auto":
            raise
        ray.init(
            address="local",  # a new cluster: not the one a stale address file names
            num_cpus=workers,
            include_dashboard=False,
            object_store_memory=LOCAL_OBJECT_STORE,
            _node_ip_address="127.0.0.1",  # loopback only: no network needed, none exposed
            **quiet,
        )
        log.info("ray_imap: started a local Ray cluster (%s CPUs)", workers or "all")
    else:
        log.info("ray_imap: connected to the Ray cluster at %s", target)
    stack.callback(ray.shutdown)
    return True


def _is_local(ray, address: str) -> bool:
    """Whether the connected cluster is one node, this driver's (same files, same Python)."""
    if address.startswith("ray://"):
        return False
    here = ray.get_runtime_context().get_node_id()
    return all(n["NodeID"] == here for n in ray.nodes() if n["Alive"])


def _kill(ray, actor) -> None:
    """End an actor this module started (already gone, or the session lost, is fine)."""
    with contextlib.suppress(Exception):
        ray.kill(actor)


def _describe(item: Any, limit: int = 500) -> str:
    """repr(item), shortened past limit characters."""
    text = repr(item)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _batches(items: Iterable[T], size: int) -> Iterator[list[T]]:
    """Consecutive chunks of at most size items."""
    it = iter(items)
    while chunk := list(itertools.islice(it, size)):
        yield chunk


def _raise_item_error(item: Any, detail: tuple[str, bytes | None]) -> None:
    """Raise RayItemError for item from the worker's (traceback, pickled error)."""
    from ray import cloudpickle

    tb, blob = detail
    cause = None
    if blob is not None:
        with contextlib.suppress(Exception):
            cause = cloudpickle.loads(blob)
    last = tb.strip().splitlines()[-1] if tb.strip() else "unknown error"
    err = RayItemError(
        item,
        f"ray_imap: fn failed on item {_describe(item)}: {last}\n"
        f"--- traceback on the Ray worker ---\n{tb}",
    )
    raise err from cause


def ray_imap(
    fn: Callable[[T], R],
    items: Iterable[T],
    address: str = "auto",
    workers: int | None = None,
    chunksize: int = 4,
) -> Iterator[R]:
    """fn(item) for each item, yielded as chunks finish (unordered), on Ray actors."""
    if chunksize < 1:
        raise ValueError(f"chunksize must be at least 1, not {chunksize}")
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be at least 1, not {workers}")
    ray = _import_ray()
    from ray.exceptions import RayActorError, RayError

    chunks = _batches(items, chunksize)
    first = next(chunks, None)
    if first is None:
        return
    chunks = itertools.chain([first], chunks)
    with contextlib.ExitStack() as stack:
        _connect(ray, address, workers, stack)
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        n_actors = min(workers or cpus, cpus)
        if hasattr(items, "__len__"):
            n_actors = min(n_actors, -(-len(items) // chunksize))
        runner = ray.remote(num_cpus=1, max_restarts=0)(_Runner).options(
            runtime_env=_runtime_env(fn, _is_local(ray, address))
        )
        actors = [runner.remote(fn) for _ in range(n_actors)]
        for actor in actors:
            stack.callback(_kill, ray, actor)
        pending: dict = {}  # ObjectRef -> (actor, chunk)

        def submit(actor) -> None:
            chunk = next(chunks, None)
            if chunk is not None:
                pending[actor.run.remote(chunk)] = (actor, chunk)

        for _ in range(1 + QUEUED_PER_ACTOR):
            for actor in actors:
                submit(actor)
        while pending:
            [ref], _ = ray.wait(list(pending), num_returns=1)
            actor, chunk = pending.pop(ref)
            try:
                results = ray.get(ref)
            except RayActorError as exc:
                raise RuntimeError(
                    f"ray_imap: the Ray worker running items {_describe(chunk)} died "
                    f"(or could not start): {exc}"
                ) from exc
            except RayError as exc:
                raise RuntimeError(
                    f"ray_imap: Ray failed on the chunk of items {_describe(chunk)}: {exc}"
                ) from exc
            submit(actor)
            failed = None
            for item, (ok, value) in zip(chunk, results):
                if ok:
                    yield value
                elif failed is None:
                    failed = (item, value)
            if failed is not None:
                _raise_item_error(*failed)
