"""The roofline of one belief update: the bytes it must move and the floating-point operations
it does, against this machine's memory bandwidth measured on the spot (``rrg-bench plan``).

An update (rrg_estimator.update.update, no transition) is

1. the likelihood row: one pass of the likelihood kernel (obs_model._log_likelihood_row) over
   the table's columns that the reading's terms use, then exp and the floor;
2. the gather and multiply: b'(w) = b(w)·L[idx(w)] / Σ b·L over the belief's N states.

Step 2 alone is the floor the issue names: it must read the prior's weights (8 B a state), the
likelihood row (4 B an entry) and the table indices in their product form (8 B per (x, y) pair
and per θ), and write the posterior (8 B a state). Step 1 must also read the table's columns
once. Both floors are printed, each at the bandwidth of main memory (a working set far larger
than the last-level cache) and at that of the cache (a working set of the update's size, as in
a benchmark that repeats one update), so the distance to the floor is measured, not claimed.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
from numba import njit

from rrg_estimator.obs_model import ObsFeatures, TableLike

MAIN_MEMORY_BYTES = 512 * 2**20  # far beyond any L3 of the machines we run on (32 MiB here)


def median_seconds(fn: Callable[[], object], repeats: int, warmup: bool = True) -> float:
    """Median wall time [s] of fn over repeats calls, after one untimed warm-up call (lazy
    loads, compilation) unless warmup is False (the slow reference runs)."""
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@njit(cache=True, fastmath=True)  # the sum may be reassociated: a vectorized read
def _read_all(a: np.ndarray) -> float:
    """Σ a, read once (numpy's own sum runs out of arithmetic before a cache runs out of
    bandwidth: about half of what this probe reads from L3 here)."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i]
    return total


def read_bandwidth(n_bytes: int, repeats: int = 5) -> float:
    """Read bandwidth [B/s] of one thread over a float64 array of n_bytes (median of repeats)."""
    a = np.ones(n_bytes // 8)
    return a.nbytes / median_seconds(lambda: _read_all(a), repeats)


def copy_bandwidth(n_bytes: int, repeats: int = 5) -> float:
    """Copy bandwidth [B/s] of one thread, counting the bytes read and written (2·n_bytes, as
    STREAM's copy does): np.copyto between two float64 arrays of n_bytes (median of repeats)."""
    src = np.ones(n_bytes // 8)
    dst = np.zeros_like(src)
    return 2 * src.nbytes / median_seconds(lambda: np.copyto(dst, src), repeats)


def likelihood_columns_bytes(table: TableLike, feats: ObsFeatures) -> int:
    """Bytes of the table's columns one reading's likelihood row reads (each once): contact
    (1 B), the silent-sensors sum (4 B), closure and its σ (2·3·4 B), and per entry 4 B of
    progress if the reading stopped early, 4 B per fired sensor and 3·4 B per fingertip point
    the reading has."""
    n = len(table.contact)
    per_entry = 1 + 4 + 24
    per_entry += 4 * bool(feats.contact[0])
    per_entry += 4 * int(np.count_nonzero(feats.sensors[0]))
    per_entry += 12 * int(np.count_nonzero(~np.isnan(feats.tip_points[0, :, 0])))
    return n * per_entry


def likelihood_flops(table: TableLike, feats: ObsFeatures) -> int:
    """Floating-point operations of one likelihood row (a min, a compare and an exp count one
    each): per entry the contact choice, 6 for the progress term if the reading stopped early,
    1 + 1 per fired sensor for the sensor terms, 3·6 for the closures, 11 per fingertip point,
    then exp and the floor's multiply and add."""
    per_entry = 1 + 6 * bool(feats.contact[0])
    per_entry += 2 + int(np.count_nonzero(feats.sensors[0]))
    per_entry += 18 + 11 * int(np.count_nonzero(~np.isnan(feats.tip_points[0, :, 0])))
    per_entry += 3
    return len(table.contact) * per_entry


def roofline(
    n_states: int,
    n_xy: int,
    n_theta: int,
    table: TableLike,
    feats: ObsFeatures,
    measured_s: float,
    repeats: int = 5,
    main_memory_bytes: int = MAIN_MEMORY_BYTES,
) -> dict:
    """The roofline section of ``rrg-bench plan --json`` for one update of a belief of
    n_states = n_xy·n_theta states by the reading ``feats`` (one row), timed at measured_s;
    main memory's bandwidth is read over arrays of main_memory_bytes."""
    gather_bytes = 8 * n_states + 4 * len(table.contact) + 8 * (n_xy + n_theta) + 8 * n_states
    gather_flops = 3 * n_states  # multiply, sum, divide
    total_bytes = gather_bytes + likelihood_columns_bytes(table, feats)
    total_flops = gather_flops + likelihood_flops(table, feats)
    memory = read_bandwidth(main_memory_bytes, repeats)
    cache = read_bandwidth(max(total_bytes, 1 << 20), max(50, 10 * repeats))
    out = {
        "main_memory_read_gbs": memory / 1e9,
        "main_memory_copy_gbs": copy_bandwidth(main_memory_bytes, repeats) / 1e9,
        "cache_read_gbs": cache / 1e9,
        "measured_update_ms": measured_s * 1e3,
        "gather_bytes": gather_bytes,
        "gather_flops": gather_flops,
        "update_bytes": total_bytes,
        "update_flops": total_flops,
        "flops_per_byte": total_flops / total_bytes,
    }
    for name, n_bytes in (("gather", gather_bytes), ("update", total_bytes)):
        for roof, bandwidth in (("memory", memory), ("cache", cache)):
            floor = n_bytes / bandwidth
            out[f"{name}_floor_{roof}_ms"] = floor * 1e3
            out[f"{name}_ratio_{roof}"] = measured_s / floor
    return out


def describe(r: dict) -> str:
    """The roofline section as text lines."""
    return "\n".join(
        [
            f"[plan] roofline: memory bandwidth (1 thread, 512 MiB) read "
            f"{r['main_memory_read_gbs']:.1f} GB/s, copy {r['main_memory_copy_gbs']:.1f} GB/s; "
            f"cache read (update-sized working set) {r['cache_read_gbs']:.1f} GB/s",
            f"[plan] roofline: gather-multiply-normalize {r['gather_bytes'] / 1e3:.0f} kB, "
            f"{r['gather_flops'] / 1e3:.0f} kflop: floor {r['gather_floor_memory_ms']:.3f} ms "
            f"(memory) / {r['gather_floor_cache_ms']:.3f} ms (cache)",
            f"[plan] roofline: whole update with the likelihood row "
            f"{r['update_bytes'] / 1e3:.0f} kB, {r['update_flops'] / 1e3:.0f} kflop "
            f"({r['flops_per_byte']:.2f} flop/B): floor "
            f"{r['update_floor_memory_ms']:.3f} ms (memory) / {r['update_floor_cache_ms']:.3f} ms "
            f"(cache)",
            f"[plan] roofline: measured {r['measured_update_ms']:.3f} ms = "
            f"{r['update_ratio_memory']:.1f}× the memory floor, {r['update_ratio_cache']:.1f}× "
            f"the cache floor of the whole update ({r['gather_ratio_memory']:.1f}× / "
            f"{r['gather_ratio_cache']:.1f}× the gather's alone)",
        ]
    )
