"""Compiled kernels of the forward search's hot path (rrg_planner/search.py).

Each kernel fuses a chain of array operations over a belief's support into one pass. Every
result that reaches a decision's value is computed with the floating-point operations, in the
order, that NumPy uses for the same expression, so it has NumPy's bits: the table index (in
float32), the cluster masses (np.bincount's order), sums (NumPy's pairwise sum,
``pairwise_sum``), the tie order of probabilities (np.round, stable sort), the merged branch
probabilities, the compacted posteriors and the goal grasp's terms (whose dot product NumPy
takes). The decisions depend on those bits where values tie:
tests/rrg_planner/test_search_equivalence.py holds them to recorded decisions. Only the
posteriors' moments, which decide which branches merge (by tolerances), are summed in any
order: in float32, vectorized over the states.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_TWO_PI = 2 * np.pi
_PI32 = np.float32(np.pi)
_TWO_PI32 = np.float32(2 * np.pi)


@njit(cache=True)
def _wrap(a: float) -> float:  # pragma: no cover - compiled
    """search._wrap of one angle [rad]: the same two operations."""
    return a - _TWO_PI * np.rint(a / _TWO_PI)


@njit(cache=True)
def _index(
    x: float, y: float, th: float, e: np.ndarray, c32, s32, spacing32, half32, shape
) -> int:  # pragma: no cover - compiled
    """search.table_index of one point (x, y, θ) [m, m, rad], in float32 as it is there."""
    dx = np.float32(x) - np.float32(e[0])
    dy = np.float32(y) - np.float32(e[1])
    ix = np.rint((c32 * dx + s32 * dy) / spacing32[0] + half32[0])
    iy = np.rint((c32 * dy - s32 * dx) / spacing32[1] + half32[1])
    shifted = np.float32(th) - np.float32(e[2]) + _PI32
    # x % 2π is x itself on [0, 2π) (fmod, then no sign fix): skip the slow remainder there
    if not (shifted >= 0 and shifted < _TWO_PI32):
        shifted = shifted % _TWO_PI32
    dth = shifted - _PI32
    it = np.rint(dth / spacing32[2] + half32[2])
    ix = min(max(ix, np.float32(0.0)), np.float32(shape[0] - 1))
    iy = min(max(iy, np.float32(0.0)), np.float32(shape[1] - 1))
    it = min(max(it, np.float32(0.0)), np.float32(shape[2] - 1))
    return (np.int64(ix) * shape[1] + np.int64(iy)) * shape[2] + np.int64(it)


@njit(cache=True)
def table_index(
    points: np.ndarray, e: np.ndarray, c: float, s: float, spacing: np.ndarray, shape: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """search.table_index (flat index (S,) of each point's offset from e), bit for bit, as
    int32 (the moments' gathers are faster on 32-bit indices); c, s: cos and sin of e[2]
    (NumPy's); spacing (3,) [m, m, rad]; shape (3,) int64."""
    c32, s32 = np.float32(c), np.float32(s)
    spacing32 = spacing.astype(np.float32)
    half32 = ((shape - 1) / 2).astype(np.float32)
    out = np.empty(points.shape[0], dtype=np.int32)
    for i in range(points.shape[0]):
        out[i] = _index(
            points[i, 0], points[i, 1], points[i, 2], e, c32, s32, spacing32, half32, shape
        )
    return out


@njit(cache=True)
def cluster_mass(
    assign: np.ndarray, idx: np.ndarray, weights: np.ndarray, count: int
) -> np.ndarray:  # pragma: no cover - compiled
    """P(c | b, a) unnormalized (count,): the weights summed by the cluster of each state's
    table entry (assign[idx], -1 for none), in state order as np.bincount sums them."""
    out = np.zeros(count)
    for i in range(idx.shape[0]):
        c = assign[idx[i]]
        if c >= 0:
            out[c] += weights[i]
    return out


@njit(cache=True)
def goal_terms(
    points: np.ndarray,
    weights: np.ndarray,
    e: np.ndarray,
    c: float,
    s: float,
    spacing: np.ndarray,
    shape: np.ndarray,
    radius: float,
    reach_theta: float,
    goal: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The weights and P(G | Δ) (from ``goal``, over the table) of the states whose offset from
    e may have P(G | Δ) > 0: within ``radius`` [m] of e in x, y and ``reach_theta`` [rad] in θ
    (the goal's reach with a cell of margin), in state order: their dot product is the goal
    grasp's P_b(G) at e."""
    c32, s32 = np.float32(c), np.float32(s)
    spacing32 = spacing.astype(np.float32)
    half32 = ((shape - 1) / 2).astype(np.float32)
    r2 = radius * radius
    w_out = np.empty(points.shape[0])
    g_out = np.empty(points.shape[0])
    n = 0
    for i in range(points.shape[0]):
        dx = points[i, 0] - e[0]
        dy = points[i, 1] - e[1]
        if dx * dx + dy * dy > r2 or abs(_wrap(points[i, 2] - e[2])) > reach_theta:
            continue
        j = _index(points[i, 0], points[i, 1], points[i, 2], e, c32, s32, spacing32, half32, shape)
        w_out[n] = weights[i]
        g_out[n] = goal[j]
        n += 1
    return w_out[:n], g_out[:n]


@njit(cache=True)
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """NumPy's pairwise sum of a[lo:lo+n] for n ≤ 128: sequential below 8 terms, else in 8
    interleaved partial sums (r_k adds the terms k, k + 8, k + 16, …)."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    end = lo + n - n % 8
    for i in range(lo + 8, end, 8):
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(end, lo + n):
        res += a[i]
    return res


@njit(cache=True)
def pairwise_sum(a: np.ndarray, lo: int = 0, n: int = -1) -> float:  # pragma: no cover - compiled
    """a[lo:lo+n].sum() (the rest of a for n < 0) as NumPy sums a contiguous float64 array,
    bit for bit: blocks of up to 128 terms (``_block_sum``), halved at multiples of 8 above
    that and added pairwise (NumPy's recursion, unrolled: numba cannot cache recursion)."""
    if n < 0:
        n = a.shape[0] - lo
    if n <= 128:
        return _block_sum(a, lo, n)
    # post-order walk of the halving tree: (start, length, children done) per open node
    starts = np.empty(64, dtype=np.int64)
    lengths = np.empty(64, dtype=np.int64)
    done = np.empty(64, dtype=np.int64)
    values = np.empty(64)
    top, n_values = 1, 0
    starts[0], lengths[0], done[0] = lo, n, 0
    while top > 0:
        node = top - 1
        start, length = starts[node], lengths[node]
        if length <= 128:
            values[n_values] = _block_sum(a, start, length)
            n_values += 1
            top -= 1
            continue
        half = length // 2
        half -= half % 8
        if done[node] == 2:  # both halves summed: left + right
            values[n_values - 2] = values[n_values - 2] + values[n_values - 1]
            n_values -= 1
            top -= 1
            continue
        starts[top] = start if done[node] == 0 else start + half
        lengths[top] = half if done[node] == 0 else length - half
        done[top] = 0
        done[node] += 1
        top += 1
    return values[0]


@njit(cache=True)
def most_probable_first(probs: np.ndarray, scale: float) -> np.ndarray:  # pragma: no cover
    """Indices ordering probabilities from the largest, ties by index: ties to the decimals of
    ``scale`` = 10**decimals, rounded as np.round(probs, decimals) rounds them (search's
    TIE_DECIMALS)."""
    keys = np.empty(probs.shape[0])
    for i in range(probs.shape[0]):
        keys[i] = -(np.rint(probs[i] * scale) / scale)
    return np.argsort(keys, kind="mergesort")


@njit(cache=True)
def weighted_features(
    points: np.ndarray, weights: np.ndarray, ref: np.ndarray, sigma: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """(11,S) float32 b · [1, d (3), d⊗d (6 unique), log b] per state, d the deviation from
    ``ref`` (θ wrapped) over ``sigma`` [m, m, rad]: summed against a likelihood L_c they give
    the moments of the posterior b·L_c (``_moments``)."""
    out = np.empty((11, points.shape[0]), dtype=np.float32)
    for i in range(points.shape[0]):
        w = weights[i]
        d0 = (points[i, 0] - ref[0]) / sigma[0]
        d1 = (points[i, 1] - ref[1]) / sigma[1]
        d2 = _wrap(points[i, 2] - ref[2]) / sigma[2]
        out[0, i] = w
        out[1, i] = w * d0
        out[2, i] = w * d1
        out[3, i] = w * d2
        out[4, i] = w * (d0 * d0)
        out[5, i] = w * (d0 * d1)
        out[6, i] = w * (d0 * d2)
        out[7, i] = w * (d1 * d1)
        out[8, i] = w * (d1 * d2)
        out[9, i] = w * (d2 * d2)
        out[10, i] = w * np.log(w) if w > 0 else 0.0
    return out


@njit(cache=True, fastmath=True)
def _moments(
    lik_row: np.ndarray, log_row: np.ndarray, idx: np.ndarray, feats: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """out (12,) = Σ_i L[idx_i] · feats[:, i] (11), then Σ_i b_i · (L log L)[idx_i]: float32
    sums in any order (vectorized)."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = s10 = s11 = np.float32(0.0)
    for i in range(idx.shape[0]):
        j = idx[i]
        lik = lik_row[j]
        s0 += lik * feats[0, i]
        s1 += lik * feats[1, i]
        s2 += lik * feats[2, i]
        s3 += lik * feats[3, i]
        s4 += lik * feats[4, i]
        s5 += lik * feats[5, i]
        s6 += lik * feats[6, i]
        s7 += lik * feats[7, i]
        s8 += lik * feats[8, i]
        s9 += lik * feats[9, i]
        s10 += lik * feats[10, i]
        s11 += log_row[j] * feats[0, i]
    out[0], out[1], out[2], out[3], out[4], out[5] = s0, s1, s2, s3, s4, s5
    out[6], out[7], out[8], out[9], out[10], out[11] = s6, s7, s8, s9, s10, s11


@njit(cache=True)
def _norm9(a: np.ndarray) -> float:  # pragma: no cover - compiled
    """The Frobenius norm of a flattened 3×3 matrix (np.linalg.norm's sum of squares)."""
    sq = np.empty(9)
    for k in range(9):
        sq[k] = a[k] * a[k]
    return np.sqrt(pairwise_sum(sq))


@njit(cache=True)
def expand_branches(
    assign: np.ndarray,
    count: int,
    likelihood: np.ndarray,
    l_log_l: np.ndarray,
    idx: np.ndarray,
    weights: np.ndarray,
    feats: np.ndarray,
    entropy_tol: float,
    cov_tol: float,
    keep_mass: float,
    tie_scale: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """ForwardSearch.expand up to its children: the clusters (K,) of the kept merged branches
    and their probabilities (K,), most probable first (search.merge_branches); feats: the
    belief's weighted_features; tie_scale: ``most_probable_first``'s. The cluster masses and
    merged probabilities are summed as the NumPy code sums them; the posteriors' moments, which
    only decide what merges, in float32 (``_moments``)."""
    pc = cluster_mass(assign, idx, weights, count)
    total = pairwise_sum(pc)
    if total <= 0:
        return np.empty(0, dtype=np.int64), np.empty(0)
    for c in range(count):
        pc[c] /= total
    order = most_probable_first(pc, tie_scale)
    # the most probable clusters that cover 95 % of the mass (np.searchsorted on the cumsum)
    acc = 0.0
    n_cand = count
    for i in range(count):
        acc += pc[order[i]]
        if acc >= 0.95:
            n_cand = i + 1
            break
    cand = np.empty(n_cand, dtype=np.int64)
    k = 0
    for i in range(n_cand):
        if pc[order[i]] > 0:
            cand[k] = order[i]
            k += 1
    cand = cand[:k]
    # each posterior's entropy and covariance (search.branch_statistics)
    probs = np.empty(k)
    ent = np.empty(k)
    covs = np.empty((k, 9))
    mom32 = np.empty(12, dtype=np.float32)
    for r in range(k):
        probs[r] = pc[cand[r]]
        _moments(likelihood[cand[r]], l_log_l[cand[r]], idx, feats, mom32)
        mom = mom32.astype(np.float64)
        z = mom[0]
        mean = (mom[1] / z, mom[2] / z, mom[3] / z)
        upper = 4
        for a in range(3):
            for b in range(a, 3):
                second = mom[upper] / z
                covs[r, 3 * a + b] = second - mean[a] * mean[b]
                covs[r, 3 * b + a] = second - mean[b] * mean[a]
                upper += 1
        ent[r] = np.log(z) - (mom[11] + mom[10]) / z
    kept, p = merge(probs, ent, covs, entropy_tol, cov_tol, keep_mass, tie_scale)
    return cand[kept], p


@njit(cache=True)
def merge(
    probs: np.ndarray,
    ent: np.ndarray,
    covs: np.ndarray,
    entropy_tol: float,
    cov_tol: float,
    keep_mass: float,
    tie_scale: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """search.merge_branches of K branches (probabilities, entropies [nats], covariances (K,9)
    flattened): the kept representatives (indices) and their renormalized probabilities, most
    probable first (ties: ``most_probable_first``): the masses are summed one branch at a time in
    that order, their total as np.sum sums it."""
    k = probs.shape[0]
    scale = np.empty(k)
    for r in range(k):
        scale[r] = max(_norm9(covs[r]), 1e-12)
    reps = np.empty(k, dtype=np.int64)
    mass = np.empty(k)
    n_reps = 0
    diff = np.empty(9)
    for kk in most_probable_first(probs, tie_scale):
        merged = False
        for ri in range(n_reps):
            r = reps[ri]
            if abs(ent[kk] - ent[r]) < entropy_tol:
                for q in range(9):
                    diff[q] = covs[kk, q] - covs[r, q]
                if _norm9(diff) / scale[r] < cov_tol:
                    mass[ri] += probs[kk]
                    merged = True
                    break
        if not merged:
            reps[n_reps] = kk
            mass[n_reps] = probs[kk]
            n_reps += 1
    mass = mass[:n_reps]
    total = pairwise_sum(mass)
    rep_order = most_probable_first(mass, tie_scale)
    kept = 0
    acc = 0.0
    for i in rep_order:
        kept += 1
        acc += mass[i]
        if acc >= keep_mass * total:
            break
    z = 0.0
    for j in range(kept):
        z += mass[rep_order[j]]
    out_k = np.empty(kept, dtype=np.int64)
    out_p = np.empty(kept)
    for j in range(kept):
        out_k[j] = reps[rep_order[j]]
        out_p[j] = mass[rep_order[j]] / z
    return out_k, out_p


@njit(cache=True)
def child_weights(
    lik_row: np.ndarray, idx: np.ndarray, weights: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """The normalized posterior b·L_c (S,) of one cluster's likelihood row, as NumPy's
    ``w = L[idx] * b; w /= w.sum()``."""
    w = np.empty(idx.shape[0])
    for i in range(idx.shape[0]):
        w[i] = np.float64(lik_row[idx[i]]) * weights[i]
    total = pairwise_sum(w)
    for i in range(w.shape[0]):
        w[i] /= total
    return w


@njit(cache=True, fastmath=True)
def _max(a: np.ndarray) -> float:  # pragma: no cover - compiled
    """The largest of finite values a (exact in any order, so vectorized; numba's a.max() checks
    every element for NaN)."""
    top = a[0]
    for i in range(1, a.shape[0]):
        top = max(top, a[i])
    return top


@njit(cache=True)
def _normalize_kept(
    weights: np.ndarray, support_rel: float, tie: float
) -> tuple[np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """SparseBelief.compact of weights (S,): the kept indices (weights ≥ support_rel of the
    largest), their renormalized weights, and w*(b)'s position among them (the first whose
    weight is at least ``tie`` times the largest), summed as NumPy sums them."""
    largest = _max(weights)  # always kept
    threshold = support_rel * largest
    keep = np.empty(weights.shape[0], dtype=np.int64)
    w = np.empty(weights.shape[0])
    n = 0
    for i in range(weights.shape[0]):
        if weights[i] >= threshold:
            keep[n] = i
            w[n] = weights[i]
            n += 1
    total = pairwise_sum(w, 0, n)
    for i in range(n):
        w[i] /= total
    # the largest normalized weight: rounding is monotonic, so it is the largest over the total
    top = largest / total * tie
    star = 0
    while w[star] < top:
        star += 1
    return keep[:n], w[:n], star


@njit(cache=True)
def _take_points(points: np.ndarray, keep: np.ndarray) -> np.ndarray:  # pragma: no cover
    """points[keep] (K,3)."""
    out = np.empty((keep.shape[0], 3))
    for i in range(keep.shape[0]):
        for k in range(3):
            out[i, k] = points[keep[i], k]
    return out


@njit(cache=True)
def compact(
    points: np.ndarray, weights: np.ndarray, support_rel: float, tie: float
) -> tuple[np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """SparseBelief.compact, bit for bit: the kept points (K,3), their renormalized weights
    (K,) and w*(b)'s index among them (``_normalize_kept``)."""
    keep, w, star = _normalize_kept(weights, support_rel, tie)
    return _take_points(points, keep), w, star


@njit(cache=True)
def compact_grid(
    weights: np.ndarray,
    support_rel: float,
    tie: float,
    ax: np.ndarray,
    ay: np.ndarray,
    at: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """``compact`` of a belief over a grid given by its axes (Grid.axes): the kept grid points
    are read off the axes instead of from all of Grid.points."""
    keep, w, star = _normalize_kept(weights, support_rel, tie)
    ny, nt = ay.shape[0], at.shape[0]
    out = np.empty((keep.shape[0], 3))
    for i in range(keep.shape[0]):
        flat = keep[i]
        out[i, 0] = ax[flat // (ny * nt)]
        out[i, 1] = ay[(flat // nt) % ny]
        out[i, 2] = at[flat % nt]
    return out, w, star


@njit(cache=True)
def child(
    lik_row: np.ndarray,
    idx: np.ndarray,
    points: np.ndarray,
    weights: np.ndarray,
    support_rel: float,
    tie: float,
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:  # pragma: no cover - compiled
    """The compact posterior b·L_c of one cluster's likelihood row: ``compact`` of
    ``child_weights``, and the indices of the kept states among the belief's."""
    keep, w, star = _normalize_kept(child_weights(lik_row, idx, weights), support_rel, tie)
    return _take_points(points, keep), w, star, keep


@njit(cache=True)
def _wrap_angle(a: float) -> float:  # pragma: no cover - compiled
    """rrg_models.poses.wrap_angle of one angle [rad]: the same remainder (skipped where it is
    the identity, on [0, 2π))."""
    shifted = a + np.pi
    if not (shifted >= 0 and shifted < _TWO_PI):
        shifted = shifted % _TWO_PI
    return shifted - np.pi


@njit(cache=True)
def mass_in_box(
    points: np.ndarray, weights: np.ndarray, e: np.ndarray, c: float, s: float, box: np.ndarray
) -> float:  # pragma: no cover - compiled
    """The weight of the states whose offset from e (relative_planar) lies in a reorientation's
    measured ``box`` (ReorientOutcome.inside), summed as NumPy sums weights[inside]; c, s: cos
    and sin of e[2] (NumPy's)."""
    inside = np.empty(points.shape[0])
    n = 0
    for i in range(points.shape[0]):
        dx = points[i, 0] - e[0]
        dy = points[i, 1] - e[1]
        x = c * dx + s * dy
        if abs(x) > box[0]:
            continue
        y = -s * dx + c * dy
        if abs(y) <= box[1] and abs(_wrap_angle(_wrap_angle(points[i, 2] - e[2]))) <= box[2]:
            inside[n] = weights[i]
            n += 1
    return pairwise_sum(inside, 0, n)
