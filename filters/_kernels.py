"""
_kernels.py
-----------
Compiled per-signal solvers of the sparse core (numba): Lasso by LARS and
orthogonal matching pursuit, one signal at a time.

The point-cloud filters code one short signal per point (d = 7-40 features,
up to 10^6 points) on one shared dictionary.  The NumPy solvers in
``sparse.py`` vectorise over signals; these kernels instead walk each signal's
own LARS path / pursuit with scalar loops and incremental correlations
(``c ← c − γ·G[:, A]·w``), which needs no padding, no screening and no
temporary (c, S) arrays.  Measured on the SDBS features (d = 7, 200 atoms):
about 2-3 µs per signal against 13-20 µs for the batched NumPy LARS, so
the kernels stay single-threaded: a parallel region would cost more to start
(≈ 0.3 s per process for numba's thread pool) than it saves below 10^6
signals.  The NumPy solvers remain the reference (the tests compare both) and the
fallback when numba is not importable.

Compiled code is cached on disk (``cache=True``): the first call after an
install compiles for a few seconds, later processes load the cache.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

#: True when the compiled kernels are available
HAVE_NUMBA = numba is not None
#: the filters use the kernels when True; set it to False to run the NumPy
#: reference implementations instead (the tests compare both)
ENABLED = HAVE_NUMBA

#: signals per work item (scratch arrays are allocated once per block)
_BLOCK = 2048
#: ridge added to the diagonal of the active Gram matrices
_RIDGE = 1e-12
#: Cholesky pivot under which a joining atom counts as linearly dependent on
#: the active ones (unit atoms: 1 − cos² of its angle to their span)
_DEGENERATE = 1e-10



def _jit(**options):
    """``numba.njit(cache=True, nogil=True, **options)``; without the on-disk
    cache when numba finds no writable place for it (a read-only install and
    home), which only costs the compile time in every process."""
    def deco(fn):
        try:
            return numba.njit(cache=True, nogil=True, **options)(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return numba.njit(nogil=True, **options)(fn)
    return deco


if HAVE_NUMBA:

    @_jit(inline="always")
    def _chol_solve(G, act, na, ridge, M, rhs, out):
        """Solve G[act, act] · out = rhs for the first ``na`` active atoms by a
        Cholesky factorisation written into ``M``."""
        for p in range(na):
            for q in range(p + 1):
                v = G[act[p], act[q]]
                if p == q:
                    v += ridge
                for r in range(q):
                    v -= M[p, r] * M[q, r]
                if p == q:
                    M[p, p] = np.sqrt(v) if v > 1e-300 else 1e-150
                else:
                    M[p, q] = v / M[q, q]
        for p in range(na):  # forward: M y = rhs
            v = rhs[p]
            for r in range(p):
                v -= M[p, r] * out[r]
            out[p] = v / M[p, p]
        for p in range(na - 1, -1, -1):  # backward: Mᵀ out = y
            v = out[p]
            for r in range(p + 1, na):
                v -= M[r, p] * out[r]
            out[p] = v / M[p, p]

    @_jit()
    def _lars_one(x, D, G, alpha, K, max_steps, act, beta, c, a, pen, g, M, w, s):
        """LARS-Lasso path of one signal down to ``alpha``.

        Writes the active atoms and their coefficients into ``act``/``beta``
        (first ``na`` entries) and returns (na, hit_max_steps).
        """
        S, d = D.shape
        best = -1.0
        j0 = 0
        for j in range(S):
            v = 0.0
            for t in range(d):
                v += D[j, t] * x[t]
            c[j] = v
            pen[j] = 0.0
            if abs(v) > best:
                best = abs(v)
                j0 = j
        for k in range(K):
            act[k] = 0
            beta[k] = 0.0
        lam = best
        if lam <= alpha:
            return 0, False
        na = 1
        act[0] = j0
        pen[j0] = np.inf
        last_drop = -1
        for _ in range(max_steps):
            for k in range(na):
                s[k] = 1.0 if c[act[k]] >= 0.0 else -1.0
            _chol_solve(G, act, na, _RIDGE, M, s, w)
            for j in range(S):
                a[j] = 0.0
            for k in range(na):
                wk = w[k]
                row = act[k]
                for j in range(S):
                    a[j] += wk * G[row, j]
            # joining: |c_j − γ a_j| = λ − γ.  Branch-free over all atoms (the
            # loop vectorises); active atoms and the atom that just left carry
            # an infinite penalty.  A non-positive denominator means "never".
            g_join = np.inf
            jj = -1
            if na < K:
                for j in range(S):
                    cj = c[j]
                    aj = a[j]
                    g1 = (lam - cj) / max(1.0 - aj, 1e-30)
                    g2 = (lam + cj) / max(1.0 + aj, 1e-30)
                    g[j] = max(min(g1, g2), 0.0) + pen[j]
                for j in range(S):
                    if g[j] < g_join:
                        g_join = g[j]
                        jj = j
            # dropping: β_k + γ w_k = 0
            g_drop = np.inf
            kk = -1
            tiny = 1e-12 * lam
            for k in range(na):
                if w[k] != 0.0:
                    gk = -beta[k] / w[k]
                    if gk > tiny and gk < g_drop:
                        g_drop = gk
                        kk = k
            g_end = lam - alpha
            gamma = g_end
            if g_join < gamma:
                gamma = g_join
            if g_drop < gamma:
                gamma = g_drop
            for k in range(na):
                beta[k] += gamma * w[k]
            for j in range(S):
                c[j] -= gamma * a[j]
            lam -= gamma
            if gamma >= g_end:
                return na, False
            if g_drop <= g_join:
                if last_drop >= 0:
                    pen[last_drop] = 0.0
                dropped = act[kk]
                last_drop = dropped  # stays blocked until the next event
                na -= 1
                act[kk] = act[na]
                beta[kk] = beta[na]
                act[na] = 0
                beta[na] = 0.0
            else:
                # an atom in the span of the active ones (a duplicate, say)
                # cannot join: its Cholesky pivot G_jj − ‖M⁻¹G_Aj‖² vanishes.
                # Its correlation stays tied with theirs, so the path goes on
                # without it; it is excluded for good (not an event).
                piv = G[jj, jj] + _RIDGE
                for p in range(na):
                    v = G[act[p], jj]
                    for r in range(p):
                        v -= M[p, r] * s[r]
                    s[p] = v / M[p, p]
                    piv -= s[p] * s[p]
                if piv < _DEGENERATE:
                    pen[jj] = np.inf
                    continue
                if last_drop >= 0:
                    pen[last_drop] = 0.0
                last_drop = -1
                act[na] = jj
                beta[na] = 0.0
                pen[jj] = np.inf
                na += 1
        return na, True

    @_jit()
    def lars_batch(X, D, G, alpha, K, max_steps):
        """LARS-Lasso codes of every row of X: (act (m, K), beta (m, K), n_hit)."""
        m = X.shape[0]
        S = D.shape[0]
        act = np.zeros((m, K), dtype=np.int64)
        beta = np.zeros((m, K))
        hit = np.zeros(m, dtype=np.bool_)
        nblk = (m + _BLOCK - 1) // _BLOCK
        for b in range(nblk):
            c = np.empty(S)
            a = np.empty(S)
            pen = np.zeros(S)
            g = np.empty(S)
            M = np.zeros((K, K))
            w = np.zeros(K)
            s = np.zeros(K)
            for i in range(b * _BLOCK, min(m, (b + 1) * _BLOCK)):
                _, h = _lars_one(X[i], D, G, alpha, K, max_steps, act[i], beta[i],
                                 c, a, pen, g, M, w, s)
                hit[i] = h
        return act, beta, int(hit.sum())

    @_jit(inline="always")
    def _minus_combination(base, coef, rows, n, A, out):
        """out = base − Σ_k coef[k] · A[rows[k]] over the first n rows."""
        for q in range(out.shape[0]):
            out[q] = base[q]
        for k in range(n):
            ck = coef[k]
            row = rows[k]
            for q in range(out.shape[0]):
                out[q] -= ck * A[row, q]

    @_jit()
    def _omp_one(x, D, G, L, tol, use_tol, eps, sup, coef, xD, c, r, M, b):
        """OMP of one signal: up to L atoms, or until ‖r‖² ≤ tol when use_tol."""
        S, d = D.shape
        xn2 = 0.0
        for t in range(d):
            xn2 += x[t] * x[t]
        for k in range(L):
            sup[k] = 0
            coef[k] = 0.0
        if use_tol and xn2 <= tol:
            return
        for j in range(S):
            v = 0.0
            for t in range(d):
                v += D[j, t] * x[t]
            xD[j] = v
            c[j] = abs(v)
        scale = np.sqrt(xn2) + 1e-300
        for t in range(L):
            for k in range(t):
                c[sup[k]] = -1.0
            j = 0
            best = c[0]
            for jj in range(1, S):
                if c[jj] > best:
                    best = c[jj]
                    j = jj
            if not best > eps * scale:
                return
            sup[t] = j
            n = t + 1
            for k in range(n):
                b[k] = xD[sup[k]]
            _chol_solve(G, sup, n, 1e-12, M, b, coef)
            if use_tol:
                _minus_combination(x, coef, sup, n, D, r)  # residual x − coef·D[s]
                rn2 = 0.0
                for q in range(d):
                    rn2 += r[q] * r[q]
                if rn2 <= tol:
                    return
            if t + 1 < L:
                # correlations with the new residual: |xD − coef·G[s]|
                _minus_combination(xD, coef, sup, n, G, c)
                for jj in range(S):
                    c[jj] = abs(c[jj])

    @_jit()
    def omp_batch(X, D, G, L, tol, use_tol, eps):
        """OMP codes of every row of X: (support (m, L), coef (m, L))."""
        m, d = X.shape
        S = D.shape[0]
        sup = np.zeros((m, L), dtype=np.int64)
        coef = np.zeros((m, L))
        nblk = (m + _BLOCK - 1) // _BLOCK
        for bk in range(nblk):
            xD = np.empty(S)
            c = np.empty(S)
            r = np.empty(d)
            M = np.zeros((L, L))
            b = np.zeros(L)
            for i in range(bk * _BLOCK, min(m, (bk + 1) * _BLOCK)):
                _omp_one(X[i], D, G, L, tol, use_tol, eps, sup[i], coef[i], xD, c, r,
                         M, b)
        return sup, coef

    @_jit()
    def ksvd_update(D, sup, coef, E, pos, starts):
        """K-SVD dictionary-update stage over every atom (Alg. 3.3 lines 5-12).

        ``E`` (m, d) holds the training residuals, ``pos`` the flat positions
        of the codes' entries grouped by atom (atom j's in
        ``pos[starts[j]:starts[j + 1]]``).  D, coef and E are updated in place;
        returns a mask of the atoms used by at least one signal.
        """
        S, d = D.shape
        L = sup.shape[1]
        used = np.zeros(S, dtype=np.bool_)
        C = np.empty((d, d))
        dj = np.empty(d)
        for j in range(S):
            p0 = starts[j]
            p1 = starts[j + 1]
            if p1 == p0:
                continue
            used[j] = True
            for a_ in range(d):
                for b_ in range(d):
                    C[a_, b_] = 0.0
            # E_j restricted to ω_j: the residual with atom j's part put back
            for q in range(p0, p1):
                r = pos[q] // L
                cf = coef[r, pos[q] % L]
                for a_ in range(d):
                    E[r, a_] += cf * D[j, a_]
                for a_ in range(d):
                    ea = E[r, a_]
                    for b_ in range(a_ + 1):
                        C[a_, b_] += ea * E[r, b_]
            for a_ in range(d):
                for b_ in range(a_):
                    C[b_, a_] = C[a_, b_]
            # rank-1 SVD of E_j through its (d × d) scatter matrix
            _, V = np.linalg.eigh(C)
            sgn = 0.0
            for a_ in range(d):
                dj[a_] = V[a_, d - 1]
                sgn += dj[a_] * D[j, a_]
            if sgn < 0.0:
                for a_ in range(d):
                    dj[a_] = -dj[a_]
            for a_ in range(d):
                D[j, a_] = dj[a_]
            for q in range(p0, p1):
                r = pos[q] // L
                new = 0.0
                for a_ in range(d):
                    new += E[r, a_] * dj[a_]
                coef[r, pos[q] % L] = new
                for a_ in range(d):
                    E[r, a_] -= new * dj[a_]
        return used

    @_jit()
    def greedy_sequential(order, rank, dist, idx, rho, ptr, extra, state):
        """The greedy removal of SDBS (6.11), sequentially: visit the points in
        ``order``; a point not yet removed is kept (state 1) and removes
        (state 2) every later point within its radius ``rho``, taken from its
        sorted k-NN list ``dist``/``idx`` and from its extra neighbours
        ``extra[ptr[i]:ptr[i + 1]]`` (exact ball queries).  ``state`` must be
        zero on entry; it is filled in place.
        """
        n, K = idx.shape
        for t in range(n):
            i = order[t]
            if state[i] == 2:
                continue
            state[i] = 1
            r = rho[i]
            for k in range(K):
                if dist[i, k] > r:
                    break
                j = idx[i, k]
                if rank[j] > t:
                    state[j] = 2
            for e in range(ptr[i], ptr[i + 1]):
                j = extra[e]
                if rank[j] > t:
                    state[j] = 2
