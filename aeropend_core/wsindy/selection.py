"""Term selection for weak SINDy: modified sequential thresholding (MSTLS) with the automatic threshold λ on a log
grid, greedy backward/forward paths and an exhaustive search of small supports, all scored by the same loss
``L = 2α‖G(w − w_LS)‖/‖G w_LS‖ + 2(1 − α)·nnz(w)/J`` (numba kernels, cached on disk).
"""
from __future__ import annotations


import numba
import numpy as np

from aeropend_core.errors import AeropendError


#: λ grid of the automatic threshold search.
THRESHOLD_GRID = np.logspace(-4.0, 0.0, 100)


# ----------------------------------------------------------------------------------------------- regression
def _regress(a: np.ndarray, b: np.ndarray, keep: np.ndarray, threshold, ridge: float, alpha: float,
             noise_gram=None, noise_rhs=None, exhaustive: int = 4, greedy: bool = True):
    """Return (w in normalised coordinates, λ used, column scales, b scale, AᵀA, Aᵀb).

    Thresholding runs on the ridge-regularised solutions (the ridge damps cancelling pairs of nearly collinear
    terms, which would otherwise both look large); the selected terms are then refitted without ridge
    (only a 1e-12 safeguard), so the ridge does not bias the reported coefficients.
    """
    ata = a.T @ a
    atb = a.T @ b
    col = np.sqrt(np.diag(ata))
    usable = col > 0
    col = np.where(usable, col, 1.0)
    bnorm = float(np.sqrt(b @ b)) or 1.0
    gram = ata / np.outer(col, col)
    rhs = atb / (col * bnorm)
    if noise_gram is not None:
        gram = gram - noise_gram / np.outer(col, col)
        rhs = rhs - noise_rhs / (col * bnorm)
    keep = keep & usable
    if threshold is None:
        grid, backward = np.zeros(0), False
    elif isinstance(threshold, str):
        if threshold != 'auto':
            raise AeropendError(f'threshold must be in (0, 1], "auto" or None, got {threshold!r}')
        grid, backward = THRESHOLD_GRID, greedy
    else:
        lam = float(threshold)
        if not 0 < lam <= 1:
            raise AeropendError(f'threshold must be in (0, 1], "auto" or None, got {threshold!r}')
        grid, backward = np.array([lam]), False
    w, lam = _select(np.ascontiguousarray(gram), np.ascontiguousarray(rhs), keep, usable, float(ridge),
                     float(alpha), np.asarray(grid, float), backward, int(exhaustive if backward else 0))
    return w, (0.0 if threshold is None else float(lam)), col, bnorm, ata, atb


@numba.njit(cache=True, nogil=True)
def _solve_subset(gram, rhs, support, ridge):
    """Least squares restricted to the support (normal equations with a relative ridge), zeros elsewhere.

    Small dense systems (at most a few tens of terms), written out to avoid per-call LAPACK overhead: Cholesky
    when every pivot exceeds 1e-8 of the largest diagonal entry, otherwise Gaussian elimination with partial
    pivoting, where a numerically zero pivot drops that direction (minimum-norm-like).
    """
    n = support.size
    idx = np.flatnonzero(support)
    k = idx.size
    w = np.zeros(n)
    if k == 0:
        return w
    a = np.empty((k, k + 1))
    scale = 0.0
    for i in range(k):
        for j in range(k):
            a[i, j] = gram[idx[i], idx[j]]
        a[i, i] += ridge
        a[i, k] = rhs[idx[i]]
        scale = max(scale, abs(a[i, i]))
    tiny = 1e-14 * max(scale, 1e-300)
    # Cholesky first (half the work); any pivot below 1e-8·scale (nearly singular or indefinite) falls back to
    # Gaussian elimination with partial pivoting below.
    low = np.zeros((k, k))
    y = np.zeros(k)
    ok = True
    for c in range(k):
        acc = a[c, c]
        for e in range(c):
            acc -= low[c, e] * low[c, e]
        if acc <= 1e-8 * scale:
            ok = False
            break
        d = np.sqrt(acc)
        low[c, c] = d
        for r in range(c + 1, k):
            v = a[r, c]
            for e in range(c):
                v -= low[r, e] * low[c, e]
            low[r, c] = v / d
        v = a[c, k]
        for e in range(c):
            v -= low[c, e] * y[e]
        y[c] = v / d
    if ok:
        for c in range(k - 1, -1, -1):
            v = y[c]
            for e in range(c + 1, k):
                v -= low[e, c] * y[e]
            y[c] = v / low[c, c]
        for i in range(k):
            w[idx[i]] = y[i]
        return w
    for c in range(k):
        p = c
        for r in range(c + 1, k):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for j in range(c, k + 1):
                a[c, j], a[p, j] = a[p, j], a[c, j]
        if abs(a[c, c]) <= tiny:
            a[c, c] = 0.0
            continue
        for r in range(c + 1, k):
            f = a[r, c] / a[c, c]
            if f != 0.0:
                for j in range(c, k + 1):
                    a[r, j] -= f * a[c, j]
    sol = np.zeros(k)
    for c in range(k - 1, -1, -1):
        if a[c, c] == 0.0:
            continue
        acc = a[c, k]
        for j in range(c + 1, k):
            acc -= a[c, j] * sol[j]
        sol[c] = acc / a[c, c]
    for i in range(k):
        w[idx[i]] = sol[i]
    return w


@numba.njit(cache=True, nogil=True)
def _best_single_change(gram, rhs, support, candidates, state, ridge, gwls, c0, denom, alpha, n_terms):
    """Set each candidate term of `support` to `state` in turn (the rest unchanged), refit, score with
    :func:`_loss`; returns (loss, index, weights) of the best change, index -1 without candidates.
    `support` is restored before returning."""
    best_loss = np.inf
    best_j = -1
    best_w = np.zeros(support.size)
    for j in range(support.size):
        if not candidates[j]:
            continue
        support[j] = state
        w = _solve_subset(gram, rhs, support, ridge)
        support[j] = not state
        value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best_loss:
            best_loss, best_j, best_w = value, j, w
    return best_loss, best_j, best_w


@numba.njit(cache=True, nogil=True)
def _best_removal(gram, rhs, support, candidates, ridge, gwls, c0, denom, alpha, n_terms):
    """:func:`_best_single_change` with ``state=False`` (drop each candidate term of ``support`` in turn), scored
    from one factorisation instead of one solve per candidate; same return value.

    With P = M⁻¹ (M the support's normal matrix plus ridge), the least squares without term p is
    w − (w_p/P_pp)·P[:, p] (exact in exact arithmetic), scored with the loss in O(k²). Only the choice of the
    term to drop uses these values: the winner is solved afresh (:func:`_solve_subset`) and scored with
    :func:`_loss`, so the weights and loss returned are those of the one-solve-per-candidate path. When a
    Cholesky pivot of M is below the threshold at which :func:`_solve_subset` leaves Cholesky (nearly collinear
    terms), the candidates are solved one by one as in :func:`_best_single_change`. A principal submatrix
    never has smaller pivots, so when M passes every candidate's solve takes the Cholesky branch too.
    """
    n = support.size
    idx = np.flatnonzero(support)
    k = idx.size
    scale = 0.0
    for i in range(k):
        scale = max(scale, abs(gram[idx[i], idx[i]] + ridge))
    low = np.zeros((k, k))
    for c in range(k):
        acc = gram[idx[c], idx[c]] + ridge
        for e in range(c):
            acc -= low[c, e] * low[c, e]
        if acc <= 1e-8 * scale:
            return _best_single_change(gram, rhs, support, candidates, False, ridge, gwls, c0, denom, alpha,
                                       n_terms)
        d = np.sqrt(acc)
        low[c, c] = d
        for r in range(c + 1, k):
            v = gram[idx[r], idx[c]]
            for e in range(c):
                v -= low[r, e] * low[c, e]
            low[r, c] = v / d
    # L⁻¹ (lower), then P = L⁻ᵀ L⁻¹ and w = P r
    inv = np.zeros((k, k))
    for c in range(k):
        inv[c, c] = 1.0 / low[c, c]
        for r in range(c + 1, k):
            v = 0.0
            for e in range(c, r):
                v -= low[r, e] * inv[e, c]
            inv[r, c] = v / low[r, r]
    p = np.zeros((k, k))
    for a in range(k):
        for b in range(a + 1):
            v = 0.0
            for e in range(a, k):
                v += inv[e, a] * inv[e, b]
            p[a, b] = v
            p[b, a] = v
    w = np.zeros(k)
    for a in range(k):
        v = 0.0
        for b in range(k):
            v += p[a, b] * rhs[idx[b]]
        w[a] = v
    best_loss = np.inf
    best_j = -1
    trial = np.empty(k)
    for q in range(k):
        if not candidates[idx[q]]:
            continue
        f = w[q] / p[q, q]
        for a in range(k):
            trial[a] = w[a] - f * p[a, q]
        trial[q] = 0.0
        acc2 = c0
        nz = 0
        for a in range(k):
            if trial[a] == 0.0:
                continue
            nz += 1
            row = 0.0
            for b in range(k):
                row += gram[idx[a], idx[b]] * trial[b]
            acc2 += trial[a] * (row - 2.0 * gwls[idx[a]])
        value = 2.0 * alpha * np.sqrt(max(acc2, 0.0)) / denom + 2.0 * (1.0 - alpha) * nz / n_terms
        if value < best_loss:
            best_loss, best_j = value, idx[q]
    if best_j < 0:
        return np.inf, -1, np.zeros(n)
    support[best_j] = False
    best_w = _solve_subset(gram, rhs, support, ridge)
    support[best_j] = True
    return _loss(gram, best_w, gwls, c0, denom, alpha, n_terms), best_j, best_w


@numba.njit(cache=True, nogil=True)
def _loss(gram, w, gwls, c0, denom, alpha, n_terms):
    """L = 2α‖G(w − w_LS)‖/‖G w_LS‖ + 2(1 − α)·nnz(w)/J with the normalised Gram matrix, in O(nnz²):
    ‖G(w − w_LS)‖² = wᵀGw − 2 wᵀ(G w_LS) + w_LSᵀ G w_LS, with gwls = G w_LS and c0 = w_LSᵀ G w_LS."""
    n = w.size
    nz = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        if w[i] != 0.0:
            nz[k] = i
            k += 1
    acc2 = c0
    for a in range(k):
        i = nz[a]
        row = 0.0
        for b in range(k):
            row += gram[i, nz[b]] * w[nz[b]]
        acc2 += w[i] * (row - 2.0 * gwls[i])
    return 2.0 * alpha * np.sqrt(max(acc2, 0.0)) / denom + 2.0 * (1.0 - alpha) * k / n_terms


@numba.njit(cache=True, nogil=True)
def _exhaustive(gram, rhs, gwls, c0, denom, alpha, n_terms, base, free, max_size, best_loss, ridge):
    """Best support (by the loss) among ``base`` plus every set of 1..max_size terms of ``free``.

    Depth-first over the combinations in lexicographic order with a Cholesky factor of the support's normal
    matrix extended by one row per added term (scaled by the stored reciprocals of its diagonal, one division per
    row), so each support costs O(k²) instead of a fresh O(k³) solve:
    with z = L⁻¹rhs_S and y = L⁻¹(Gw_LS)_S the loss numerator is c0 + ‖z‖² − 2 zᵀy (same value as
    :func:`_loss` on the subset solution). Supports whose factor breaks down (numerically collinear terms) are
    scored with :func:`_solve_subset`, as before. A size is not entered once its sparsity penalty alone
    reaches the best loss. Returns the best support (bool mask), or an empty array when none beats best_loss.
    """
    n = gram.shape[0]
    nb = 0
    for i in range(n):
        if base[i]:
            nb += 1
    kmax = nb + max_size
    idx = np.empty(kmax, np.int64)
    lmat = np.zeros((kmax, kmax))
    dinv = np.zeros(kmax)            # reciprocals of L's diagonal: one division per added row, not one per entry
    z = np.zeros(kmax)
    y = np.zeros(kmax)
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(gram[i, i]))
    tiny = 1e-13 * max(scale, 1e-300)
    penalty = 2.0 * (1.0 - alpha) / n_terms
    best = best_loss
    best_combo = np.empty(0, np.int64)
    # factor of the base (kept terms); a singular base falls back to full solves everywhere
    k = 0
    broken = False
    for i in range(n):
        if base[i]:
            idx[k] = i
            k += 1
    for a in range(nb):
        acc = gram[idx[a], idx[a]] + ridge
        for c in range(a):
            acc -= lmat[a, c] * lmat[a, c]
        if acc <= tiny:
            broken = True
            break
        lmat[a, a] = np.sqrt(acc)
        dinv[a] = 1.0 / lmat[a, a]
        for r in range(a + 1, nb):
            v = gram[idx[r], idx[a]]
            for c in range(a):
                v -= lmat[r, c] * lmat[a, c]
            lmat[r, a] = v * dinv[a]
    if not broken:
        for a in range(nb):
            zr = rhs[idx[a]]
            yr = gwls[idx[a]]
            for c in range(a):
                zr -= lmat[a, c] * z[c]
                yr -= lmat[a, c] * y[c]
            z[a] = zr * dinv[a]
            y[a] = yr * dinv[a]
    nf = free.size
    combo = np.zeros(max_size, np.int64)
    # ok[d]: the factor of base + combo[:d] is valid (rows 0..nb+d-1)
    ok = np.zeros(max_size + 1, np.bool_)
    ok[0] = not broken
    sz = np.zeros(max_size + 1)   # running ‖z‖² − 2 zᵀy
    for a in range(nb):
        sz[0] += z[a] * z[a] - 2.0 * z[a] * y[a]
    placed = np.zeros(max_size, np.bool_)
    depth = 0            # position being varied: base + combo[:depth] is fixed
    combo[0] = -1
    support = base.copy()
    while True:
        if placed[depth]:
            support[free[combo[depth]]] = False
            placed[depth] = False
        nxt = combo[depth] + 1
        if nxt >= nf or penalty * (nb + depth + 1) >= best - 1e-12:
            if depth == 0:
                break
            depth -= 1
            continue
        combo[depth] = nxt
        j = free[nxt]
        support[j] = True
        placed[depth] = True
        row = nb + depth
        idx[row] = j
        value = np.inf
        ok[depth + 1] = False
        if ok[depth]:
            for c in range(row):
                v = gram[idx[c], j]
                for e in range(c):
                    v -= lmat[row, e] * lmat[c, e]
                lmat[row, c] = v * dinv[c]
            acc = gram[j, j] + ridge
            for c in range(row):
                acc -= lmat[row, c] * lmat[row, c]
            if acc > tiny:
                zr = rhs[j]
                yr = gwls[j]
                for c in range(row):
                    zr -= lmat[row, c] * z[c]
                    yr -= lmat[row, c] * y[c]
                # z_row = zr/√acc, y_row = yr/√acc: the new row adds (zr² − 2·zr·yr)/acc to ‖z‖² − 2 zᵀy
                sz[depth + 1] = sz[depth] + (zr * zr - 2.0 * zr * yr) / acc
                ok[depth + 1] = True
                if depth + 1 < max_size and nxt + 1 < nf:     # descending from here: the row is needed
                    d = np.sqrt(acc)
                    lmat[row, row] = d
                    dinv[row] = 1.0 / d
                    z[row] = zr * dinv[row]
                    y[row] = yr * dinv[row]
                # the loss (one square root) only when the accuracy term can bring it below the best
                limit = (best - 1e-12 - penalty * (row + 1)) * denom / (2.0 * alpha)
                numerator = max(c0 + sz[depth + 1], 0.0)
                if limit > 0.0 and numerator <= limit * limit * (1.0 + 1e-9):
                    value = 2.0 * alpha * np.sqrt(numerator) / denom + penalty * (row + 1)
        if not ok[depth + 1]:
            w = _solve_subset(gram, rhs, support, ridge)
            value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best - 1e-12:
            best = value
            best_combo = combo[:depth + 1].copy()
        if depth + 1 < max_size and nxt + 1 < nf:
            depth += 1
            combo[depth] = nxt
    if best_combo.size == 0:
        return np.zeros(0, np.bool_)
    out = base.copy()
    for i in range(best_combo.size):
        out[free[best_combo[i]]] = True
    return out


#: Libraries of up to this many terms key their memo of solves by a bit mask of the support (an int64).
MASK_TERMS = 62


@numba.njit(cache=True, nogil=True)
def _support_key(support):
    """The support as an integer bit mask (bit i = term i; n <= MASK_TERMS terms), for cheap memo look-ups."""
    key = 0
    for i in range(support.size):
        if support[i]:
            key |= 1 << i
    return key


@numba.njit(cache=True, nogil=True)
def _memo_solve(keys, vals, counts, slot, gram, rhs, support, ridge):
    """:func:`_solve_subset` through a small ring buffer of recent (support, solution) pairs, keyed by the
    support's bit mask (:func:`_support_key`; an integer compare per entry instead of an array compare)."""
    if support.size > MASK_TERMS:         # no bit mask for so many terms: solve every time
        return _solve_subset(gram, rhs, support, ridge)
    key = _support_key(support)
    for i in range(counts[slot]):
        if keys[i] == key:
            return vals[i].copy()
    w = _solve_subset(gram, rhs, support, ridge)
    i = counts[slot + 1]
    keys[i] = key
    vals[i] = w
    counts[slot + 1] = (i + 1) % keys.shape[0]
    counts[slot] = min(counts[slot] + 1, keys.shape[0])
    return w


@numba.njit(cache=True, nogil=True)
def _select(gram, rhs, keep, usable, ridge, alpha, grid, backward, exhaustive):
    """MSTLS over the λ grid (+ optional backward elimination), scored by the loss; returns (w, λ).

    Normalised coordinates: |w_i| is the relative contribution of term i. λ = NaN when the backward path won;
    with an empty grid and no backward path, the plain (near ridge-free) least squares on all usable terms.
    """
    final_ridge = 1e-12
    w_ls = _solve_subset(gram, rhs, usable, final_ridge)
    if grid.size == 0 and not backward:
        return w_ls, 0.0
    gwls = gram @ w_ls
    c0 = w_ls @ gwls
    denom = np.sqrt(max(c0, 0.0))
    if denom == 0.0:
        denom = 1.0
    n_terms = max(np.count_nonzero(usable), 1)
    best_loss = np.inf
    best_w = w_ls
    best_lam = 0.0
    w_full = _solve_subset(gram, rhs, usable, ridge)
    # Neighbouring λ mostly visit the same supports: remember recent solves (ridge ones and final ones), keyed
    # by the support's bit mask; libraries of more than 62 terms do not fit a mask and solve every time.
    n = usable.size
    cap = 64 if n <= MASK_TERMS else 1
    ridge_keys = np.zeros(cap, np.int64)
    ridge_vals = np.zeros((cap, n))
    final_keys = np.zeros(cap, np.int64)
    final_vals = np.zeros((cap, n))
    counts = np.zeros(4, np.int64)          # ridge count, ridge next slot, final count, final next slot
    support = np.empty(n, np.bool_)
    new = np.empty(n, np.bool_)
    nonzero = np.empty(n, np.bool_)
    # The thresholding path at λ (its supports and solves) stays the same for a larger λ' as long as no weight it
    # kept crosses the bounds: λ' <= the smallest kept free |w| and 1/λ' >= the largest (weights dropped below λ
    # or above 1/λ stay dropped). Then it ends on the same support, scored already: that λ' is skipped.
    kept_min = -1.0
    kept_max = np.inf
    previous_lam = np.inf
    for lam in grid:
        upper = 1.0 / lam
        if previous_lam <= lam <= kept_min and kept_max <= upper:
            continue
        previous_lam = lam
        kept_min = np.inf
        kept_max = 0.0
        support[:] = usable
        w = w_full
        for _ in range(n + 1):
            # new = support & ((λ <= |w| <= 1/λ) | keep), without temporaries
            changed = False
            for i in range(n):
                size = abs(w[i])
                within = size >= lam and size <= upper
                inside = support[i] and (within or keep[i])
                new[i] = inside
                if inside != support[i]:
                    changed = True
                if inside and within and not keep[i]:
                    kept_min = min(kept_min, size)
                    kept_max = max(kept_max, size)
            if not changed:
                break
            support[:] = new
            w = _memo_solve(ridge_keys, ridge_vals, counts, 0, gram, rhs, support, ridge)
        for i in range(n):
            nonzero[i] = w[i] != 0.0
        # a support scored before cannot beat the best loss (which only decreases): skip it
        if n <= MASK_TERMS:
            seen = False
            key = _support_key(nonzero)
            for i in range(counts[2]):
                if final_keys[i] == key:
                    seen = True
                    break
            if seen:
                continue
        w = _memo_solve(final_keys, final_vals, counts, 2, gram, rhs, nonzero, final_ridge)
        value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
        if value < best_loss - 1e-12:
            best_loss, best_w, best_lam = value, w, lam
    if backward:
        # Greedy backward elimination scored by the same loss: with nearly collinear candidates (sin y, y, y²,
        # cos y, 1) the thresholding path can drop a true term early and never visit the true support; removing
        # one term at a time (the one whose removal changes the fit least) does visit it.
        support = usable.copy()
        while np.count_nonzero(support) > np.count_nonzero(keep):
            trial_loss, trial_j, trial_w = _best_removal(gram, rhs, support, support & ~keep, final_ridge, gwls, c0,
                                                         denom, alpha, n_terms)
            if trial_j < 0:
                break
            support[trial_j] = False
            if trial_loss < best_loss - 1e-12:
                best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
        # Greedy forward selection, same loss: adds the strongest single explanations first (sin y before its
        # polynomial look-alikes), which the backward path can miss when a whole look-alike group is present.
        support = keep & usable
        while np.count_nonzero(support) < np.count_nonzero(usable):
            # the sparsity penalty only grows along this path: once it alone reaches the best loss, stop
            if 2.0 * (1.0 - alpha) * (np.count_nonzero(support) + 1) / n_terms >= best_loss - 1e-12:
                break
            trial_loss, trial_j, trial_w = _best_single_change(gram, rhs, support, usable & ~support, True, final_ridge,
                                                               gwls, c0, denom, alpha, n_terms)
            if trial_j < 0:
                break
            support[trial_j] = True
            if trial_loss < best_loss - 1e-12:
                best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
        # Exhaustive search over small supports (keep + up to ``exhaustive`` free terms): greedy paths fail when
        # the true terms only explain the data together (thrust and gravity nearly cancel at equilibrium) while a
        # polynomial look-alike group of sin y explains part of it.
        free = np.flatnonzero(usable & ~keep)
        if exhaustive > 0 and free.size:
            support = _exhaustive(gram, rhs, gwls, c0, denom, alpha, n_terms, keep & usable, free,
                                  min(exhaustive, free.size), best_loss, final_ridge)
            if support.size:
                w = _solve_subset(gram, rhs, support, final_ridge)
                value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
                if value < best_loss - 1e-12:
                    best_loss, best_w, best_lam = value, w, np.nan
        # Local search from the best support: single additions or removals while they lower the loss.
        support = best_w != 0.0
        for _ in range(2 * usable.size):
            trial_loss = best_loss
            trial_j = -1
            trial_w = best_w
            for j in range(support.size):
                if not usable[j] or (keep[j] and support[j]):
                    continue
                support[j] = not support[j]
                w = _solve_subset(gram, rhs, support, final_ridge)
                support[j] = not support[j]
                value = _loss(gram, w, gwls, c0, denom, alpha, n_terms)
                if value < trial_loss - 1e-12:
                    trial_loss, trial_j, trial_w = value, j, w
            if trial_j < 0:
                break
            support[trial_j] = not support[trial_j]
            best_loss, best_w, best_lam = trial_loss, trial_w, np.nan
    return best_w, best_lam
