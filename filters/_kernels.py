"""
_kernels.py
-----------
Compiled kernels (numba): the per-signal solvers of the sparse core (Lasso by
LARS and orthogonal matching pursuit, one signal at a time), the per-problem
Lasso of ``lasso_batched``, the k-NN graph orientation of
``neighbors.orient_normals_mst`` (Kruskal with a signed union-find), the
chaining of nearby points (``multiscale.chain_labels``, a union-find), the
per-neighbourhood geometry of the saliency filter, the multi-scale moments
of the feature and hole detectors (``multiscale.scale_moments``), the hole
detector's strip extent (``_border.strip_extent_at``) and empty angle
(``_border.border_gap``), and the tiler's grid cells and their counting sort
(``tiles._cell_ids``, ``tiles._fill_cells``).
Each has a NumPy reference that runs when ``ENABLED`` is False; the tests
compare the two.

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

import contextvars
import os
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

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



#: True in work that must run on one thread (``single_threaded``)
_ONE_THREAD = contextvars.ContextVar("pcprep_one_thread", default=False)


@contextmanager
def single_threaded():
    """Run the row kernels and the k-d tree queries of this context on one
    thread.  The tile tasks run so on Dask workers, where each worker thread
    is meant to keep one core busy (Dask's nannies give their workers one BLAS
    and OpenMP thread for the same reason): a task that started threads of its
    own would share its core with them and with the other workers' tasks."""
    token = _ONE_THREAD.set(True)
    try:
        yield
    finally:
        _ONE_THREAD.reset(token)


def tree_workers() -> int:
    """``workers=`` for scipy's k-d tree queries: every core, or one inside
    ``single_threaded``."""
    return 1 if _ONE_THREAD.get() else -1


def threads() -> int:
    """Threads for the row kernels: one inside ``single_threaded``, else the
    cores this process may run on (its affinity), at most 4."""
    if _ONE_THREAD.get():
        return 1
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


#: rows per task of :func:`run_chunks` for kernels that allocate only per call:
#: big enough that the pool's overhead is small, small enough to balance
TASK_ROWS = 8192


def run_chunks(fn, n: int, chunk: int) -> list:
    """Call ``fn(s, e)`` over [0, n) in chunks of ``chunk`` rows on a thread
    pool of :func:`threads` (the compiled kernels release the GIL); results in
    order.  Every row's result depends on that row alone, so the chunking
    changes nothing but the time."""
    bounds = [(s, min(n, s + chunk)) for s in range(0, n, chunk)]
    nw = threads()
    if nw == 1 or len(bounds) == 1:
        return [fn(s, e) for s, e in bounds]
    with ThreadPoolExecutor(max_workers=nw) as ex:
        return list(ex.map(lambda b: fn(*b), bounds))


def stack_parts(parts: list, count: int) -> tuple:
    """The first ``count`` arrays of each chunk's result (``run_chunks``),
    each concatenated over the chunks in order."""
    return tuple(np.concatenate([q[t] for q in parts]) for t in range(count))


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

    @_jit()
    def _lasso_kkt_try(G, c, lam, coef, act, kkt_tol, ridge, idx, M, rhs, sol, a, grad):
        """Exact Lasso point on the support ``act`` with the signs of ``coef``:
        solve ``G_AA a_A = c_A − λ s_A`` and check the KKT conditions (signs
        kept, inactive |c − G a| ≤ λ, stationarity on the support).  Writes the
        point into ``a`` and returns whether it is certified."""
        m = c.shape[0]
        na = 0
        for j in range(m):
            if act[j]:
                idx[na] = j
                rhs[na] = c[j] - (lam if coef[j] > 0.0 else -lam)
                na += 1
        _chol_solve(G, idx, na, ridge, M, rhs, sol)
        for j in range(m):
            a[j] = 0.0
        for p in range(na):
            if not np.isfinite(sol[p]):
                return False
            a[idx[p]] = sol[p]
        cmax = 1.0
        for j in range(m):
            cmax = max(cmax, abs(c[j]))
            v = c[j]
            for k in range(na):
                v -= G[j, idx[k]] * sol[k]
            grad[j] = v
        scale = max(lam, 1e-300) * (1.0 + kkt_tol)
        for j in range(m):
            if act[j]:
                s = 1.0 if coef[j] > 0.0 else -1.0
                if not a[j] * s > 0.0:
                    return False
                if not abs(grad[j] - lam * s) <= kkt_tol * cmax:
                    return False
            elif not abs(grad[j]) <= scale:
                return False
        return True

    @_jit()
    def _lasso_polish(G, c, lam, coef, kkt_tol, ridge, sdiag, drop_one, act, prev,
                      idx, M, rhs, sol, a, grad):
        """The exact step of :func:`_lasso_one`: the support of ``coef``, then
        three pruned supports (coordinate descent creeps toward zero on atoms
        that leave the support), then, when ``drop_one``, the support less one
        atom.  Returns whether one of them is certified (its point in ``a``)."""
        m = c.shape[0]
        top = 0.0
        for j in range(m):
            act[j] = coef[j] != 0.0
            prev[j] = act[j]
            top = max(top, abs(coef[j]) * sdiag[j])
        if _lasso_kkt_try(G, c, lam, coef, act, kkt_tol, ridge, idx, M, rhs, sol, a,
                          grad):
            return True
        for rel in (1e-6, 1e-3, 3e-2):
            same = True
            for j in range(m):
                act[j] = abs(coef[j]) * sdiag[j] > rel * top
                same = same and act[j] == prev[j]
                prev[j] = act[j]
            if not same and _lasso_kkt_try(G, c, lam, coef, act, kkt_tol, ridge, idx,
                                           M, rhs, sol, a, grad):
                return True
        if drop_one:
            for j0 in range(m):
                if coef[j0] == 0.0:
                    continue
                for j in range(m):
                    act[j] = coef[j] != 0.0 and j != j0
                if _lasso_kkt_try(G, c, lam, coef, act, kkt_tol, ridge, idx, M, rhs,
                                  sol, a, grad):
                    return True
        return False

    @_jit()
    def _lasso_one(x, D, lam, max_iter, tol, kkt_tol, drop_one, G, c, coef, g, diag,
                   sdiag, act, prev, idx, M, rhs, sol, a, grad):
        """Lasso ``½‖x − D α‖² + λ‖α‖₁`` of one signal with its own dictionary
        by cyclic coordinate descent on ``G = DᵀD`` and ``c = Dᵀx``, with the
        exact step of :func:`_lasso_polish` after sweeps 2, 4, 8, 16, 32, every
        64th and the last (supports less one atom only after the last, when
        ``drop_one``).  ``coef`` receives the solution;
        returns (sweeps, converged)."""
        d, m = D.shape
        trace = 0.0
        cmax = 1.0
        for j in range(m):
            v = 0.0
            for t in range(d):
                v += D[t, j] * x[t]
            c[j] = v
            g[j] = v
            coef[j] = 0.0
            cmax = max(cmax, abs(v))
            for k in range(j + 1):
                w = 0.0
                for t in range(d):
                    w += D[t, j] * D[t, k]
                G[j, k] = w
                G[k, j] = w
            diag[j] = G[j, j]
            sdiag[j] = np.sqrt(diag[j])
            trace += diag[j]
        ridge = 1e-13 * max(trace, 1e-300)
        stop = tol * cmax
        for sweep in range(1, max_iter + 1):
            change = 0.0
            for j in range(m):
                if not diag[j] > 0.0:
                    continue
                old = coef[j]
                z = g[j] + diag[j] * old
                if z > lam:
                    new = (z - lam) / diag[j]
                elif z < -lam:
                    new = (z + lam) / diag[j]
                else:
                    new = 0.0
                delta = new - old
                if delta != 0.0:
                    coef[j] = new
                    for k in range(m):
                        g[k] -= G[j, k] * delta
                    change = max(change, abs(delta) * sdiag[j])
            done = change <= stop
            last = sweep == max_iter
            if (last or sweep == 2 or sweep == 4 or sweep == 8
                    or sweep == 16 or sweep == 32 or sweep % 64 == 0):
                if _lasso_polish(G, c, lam, coef, kkt_tol, ridge, sdiag,
                                 last and drop_one, act, prev, idx, M, rhs, sol, a,
                                 grad):
                    for j in range(m):
                        coef[j] = a[j]
                    return sweep, True
            if done:
                return sweep, True
        return max_iter, False

    @_jit()
    def lasso_stack(X, D, lam, max_iter, tol, kkt_tol, drop_one):
        """Lasso codes of every X[i] against its own dictionary D[i] (atoms in
        the columns) with weight lam[i]: (coef (n, m), converged (n,), the
        largest number of sweeps)."""
        n, d, m = D.shape
        coef = np.zeros((n, m))
        conv = np.zeros(n, dtype=np.bool_)
        G = np.empty((m, m))
        M = np.zeros((m, m))
        c = np.empty(m)
        g = np.empty(m)
        diag = np.empty(m)
        sdiag = np.empty(m)
        act = np.zeros(m, dtype=np.bool_)
        prev = np.zeros(m, dtype=np.bool_)
        idx = np.zeros(m, dtype=np.int64)
        rhs = np.empty(m)
        sol = np.empty(m)
        a = np.empty(m)
        grad = np.empty(m)
        most = 0
        for i in range(n):
            it, ok = _lasso_one(X[i], D[i], lam[i], max_iter, tol, kkt_tol, drop_one,
                                G, c, coef[i], g, diag, sdiag, act, prev, idx, M, rhs,
                                sol, a, grad)
            conv[i] = ok
            most = max(most, it)
        return coef, conv, most

    @_jit()
    def orient_keep(nb, lo, hi, keep, per_row):
        """Rows lo:hi of the edge choice of ``orient_edges``: row i keeps
        neighbour j when i < j or when i is not among j's neighbours (each
        undirected edge once); ``per_row`` counts the kept ones."""
        m = nb.shape[1]
        for i in range(lo, hi):
            cnt = 0
            for k in range(m):
                j = nb[i, k]
                mutual = False
                if i >= j:
                    for q in range(m):
                        if nb[j, q] == i:
                            mutual = True
                            break
                keep[i, k] = not mutual
                cnt += 0 if mutual else 1
            per_row[i] = cnt

    @_jit()
    def orient_emit(points, normals, nb, mirror, keep, start, lo, hi, ei, ej, cost, sign):
        """Rows lo:hi of ``orient_edges``' output, row i's kept edges from
        position start[i]: its ends, its cost 1 − |agreement| + 1e-6 as float32
        and the sign of the agreement (the plain n_i·n_j, or with ``mirror``
        the chord-mirrored product when that is larger in magnitude)."""
        m = nb.shape[1]
        for i in range(lo, hi):
            t = start[i]
            for k in range(m):
                if not keep[i, k]:
                    continue
                j = nb[i, k]
                plain = (normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1]
                         + normals[i, 2] * normals[j, 2])
                agree = plain
                if mirror:
                    e0 = points[j, 0] - points[i, 0]
                    e1 = points[j, 1] - points[i, 1]
                    e2 = points[j, 2] - points[i, 2]
                    ee = e0 * e0 + e1 * e1 + e2 * e2
                    a = normals[i, 0] * e0 + normals[i, 1] * e1 + normals[i, 2] * e2
                    b = normals[j, 0] * e0 + normals[j, 1] * e1 + normals[j, 2] * e2
                    mir = plain - 2.0 * a * b / (ee if ee > 0.0 else 1.0)
                    if abs(mir) > abs(plain):
                        agree = mir
                ei[t] = i
                ej[t] = j
                cost[t] = np.float32(1.0 - abs(agree) + 1e-6)
                sign[t] = -1 if agree < 0.0 else 1
                t += 1

    @_jit(inline="always")
    def _find(parent, parity, i):
        """Root of i in the union-find forest and the parity (±1) of i relative
        to it; compresses the path."""
        r = i
        p = 1
        while parent[r] != r:
            p *= parity[r]
            r = parent[r]
        # second pass: point every node of the path at r with its own parity
        q = 1
        while parent[i] != r and parent[i] != i:
            nxt = parent[i]
            pi = parity[i]
            parity[i] = p * q
            parent[i] = r
            q *= pi
            i = nxt
        return r, p

    @_jit()
    def kruskal_signs(order, ei, ej, sign, n):
        """Kruskal's minimum spanning forest over the edges in ``order`` (by
        cost), tracking through a union-find with parity the sign of every
        node relative to its component's representative: joining i and j by an
        edge of agreement sign s makes sign(i)·sign(j) = s.  Returns
        (representative (n,), relative sign (n,) int8)."""
        parent = np.arange(n)
        parity = np.ones(n, dtype=np.int8)
        size = np.ones(n, dtype=np.int64)
        for t in range(order.shape[0]):
            e = order[t]
            ri, pi = _find(parent, parity, ei[e])
            rj, pj = _find(parent, parity, ej[e])
            if ri == rj:
                continue
            p = np.int8(sign[e] * pi * pj)
            if size[ri] < size[rj]:
                ri, rj = rj, ri
            parent[rj] = ri
            parity[rj] = p
            size[ri] += size[rj]
        rep = np.empty(n, dtype=np.int64)
        rel = np.empty(n, dtype=np.int8)
        for i in range(n):
            r, p = _find(parent, parity, i)
            rep[i] = r
            rel[i] = p
        return rep, rel

    @_jit(inline="always")
    def _root(parent, i):
        """Root of i in a union-find forest, halving the path on the way."""
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    @_jit()
    def join_min(parent, a, b):
        """Join a[t] and b[t] in the union-find forest ``parent`` for every t,
        the larger root going under the smaller, so that every tree's root is
        its smallest member (``multiscale.chain_labels``)."""
        for t in range(a.shape[0]):
            x = _root(parent, a[t])
            y = _root(parent, b[t])
            if x < y:
                parent[y] = x
            elif y < x:
                parent[x] = y

    @_jit()
    def cell_ids(xyz, lo, sides, shape, out):
        """out[i] ← the C-order number of the grid cell of row i:
        ⌊(x − lo) / side⌋ per axis, clipped to the grid, in one pass (the
        NumPy reference, ``tiles._cell_ids``, makes five temporaries of the
        rows and took 3× as long in the tile grid's bisection)."""
        for i in range(xyz.shape[0]):
            c = 0
            for a in range(3):
                v = np.int64(np.floor((xyz[i, a] - lo[a]) / sides[a]))
                if v < 0:
                    v = 0
                elif v > shape[a] - 1:
                    v = shape[a] - 1
                c = c * shape[a] + v
            out[i] = c

    @_jit()
    def cell_fill(ids, pts, row0, fill, order, xyz):
        """A counting sort's scatter: row i of a chunk (input row row0 + i)
        goes to slot fill[ids[i]] of ``order`` and ``xyz``, which then moves
        on by one; rows keep their input order within a cell."""
        for i in range(ids.shape[0]):
            c = ids[i]
            p = fill[c]
            order[p] = row0 + i
            for a in range(3):
                xyz[p, a] = pts[i, a]
            fill[c] = p + 1

    @_jit(inline="always")
    def _tie_before(d1, i1, d2, i2, data):
        """(d1, neighbour i1) ranks before (d2, i2): by distance, then the
        neighbour's x, y, z, then its row."""
        if d1 != d2:
            return d1 < d2
        for c in range(3):
            if data[i1, c] != data[i2, c]:
                return data[i1, c] < data[i2, c]
        return i1 < i2

    @_jit()
    def settle_ties(dist, idx, data):
        """Every row of the neighbour lists (dist, idx), sorted by distance
        already, reordered in place by (distance, the neighbour's x, y, z,
        row) (``neighbors.query_settled``).  An insertion sort: entries move
        only within runs of equal distances, so a row costs its length plus
        the square of its runs' lengths."""
        for r in range(dist.shape[0]):
            for j in range(1, dist.shape[1]):
                dj, ij = dist[r, j], idx[r, j]
                t = j - 1
                while t >= 0 and _tie_before(dj, ij, dist[r, t], idx[r, t], data):
                    dist[r, t + 1], idx[r, t + 1] = dist[r, t], idx[r, t]
                    t -= 1
                dist[r, t + 1], idx[r, t + 1] = dj, ij

    @_jit()
    def merge_sorted(a, b, out):
        """out ← the sorted union of the sorted arrays a and b (a's element
        first on equal values)."""
        i = j = t = 0
        while i < a.shape[0] and j < b.shape[0]:
            if a[i] <= b[j]:
                out[t] = a[i]
                i += 1
            else:
                out[t] = b[j]
                j += 1
            t += 1
        out[t:t + a.shape[0] - i] = a[i:]
        t += a.shape[0] - i
        out[t:] = b[j:]

    @_jit(inline="always")
    def _select_bin(v, lo, scale, nbins):
        b = np.floor((v - lo) * scale)
        return 0 if b < 0 else (nbins - 1 if b > nbins - 1 else int(b))

    @_jit()
    def select_window(c, rlo, rscale, ra, rb, lo, scale, counts, out, count):
        """One chunk of ``neighbors._middle``: the values of ``c`` that every
        round r so far put in its kept bins (bin of rlo[r], rscale[r] in
        [ra[r], rb[r]], ``len(counts)`` bins) form the window; with ``count``
        each is counted in its bin of (lo, scale) into ``counts``, else
        copied to ``out``.  Returns (how many, their min, their max)."""
        nbins = counts.shape[0]
        m = 0
        vmin, vmax = np.inf, -np.inf
        for i in range(c.shape[0]):
            v = c[i]
            keep = True
            for r in range(rlo.shape[0]):
                b = _select_bin(v, rlo[r], rscale[r], nbins)
                if b < ra[r] or b > rb[r]:
                    keep = False
                    break
            if not keep:
                continue
            if count:
                counts[_select_bin(v, lo, scale, nbins)] += 1
            else:
                out[m] = v
            m += 1
            vmin = min(vmin, v)
            vmax = max(vmax, v)
        return m, vmin, vmax

    @_jit()
    def hood_mean(idx, count, values):
        """Mean of ``values`` (n, q) over the first count[i] entries of idx[i]."""
        n = idx.shape[0]
        q = values.shape[1]
        out = np.zeros((n, q))
        for i in range(n):
            c = count[i]
            for k in range(c):
                j = idx[i, k]
                for t in range(q):
                    out[i, t] += values[j, t]
            for t in range(q):
                out[i, t] /= c
        return out

    @_jit()
    def _sign_by_skew(diff, c, fr, a):
        """+1/−1: the sign that makes the third moment of the projections on
        axis ``a`` positive (the farthest projection when it nearly vanishes)."""
        skew = 0.0
        ss = 0.0
        far = 0.0
        best = -1.0
        for k in range(c):
            p = diff[k, 0] * fr[0, a] + diff[k, 1] * fr[1, a] + diff[k, 2] * fr[2, a]
            skew += p * p * p
            ss += p * p
            if abs(p) > best:
                best = abs(p)
                far = p
        v = skew if abs(skew) > 1e-6 * ss ** 1.5 else far
        return -1.0 if v < 0.0 else 1.0

    @_jit()
    def saliency_geometry(points, idx, count, r, n_rays, lo, hi, frames, gauss, total,
                          atoms):
        """Rows lo:hi of the neighbourhoods, in one pass: the PCA frame with
        data-fixed signs (into ``frames``), the quadric's Gaussian and total
        curvature (``gauss``, ``total``) and the ray atoms (``atoms``); the
        compiled form of ``saliency.local_frames_and_curvature`` and
        ``saliency._ray_atoms`` (same rules, see there)."""
        kmax = idx.shape[1]
        ends = np.empty((n_rays, 2))
        for m in range(n_rays):
            th = 2.0 * np.pi * m / n_rays
            ends[m, 0] = r * np.cos(th)
            ends[m, 1] = r * np.sin(th)
        diff = np.empty((kmax, 3))
        loc = np.empty((kmax, 3))
        cov = np.empty((3, 3))
        fr = np.empty((3, 3))
        M = np.empty((6, 6))
        L = np.zeros((6, 6))
        rhs = np.empty(6)
        q = np.empty(6)
        row = np.empty(6)
        sel = np.arange(6)
        for i in range(lo, hi):
            c = count[i]
            m0 = 0.0
            m1 = 0.0
            m2 = 0.0
            for k in range(c):
                j = idx[i, k]
                m0 += points[j, 0]
                m1 += points[j, 1]
                m2 += points[j, 2]
            m0 /= c
            m1 /= c
            m2 /= c
            for a in range(3):
                for b in range(3):
                    cov[a, b] = 0.0
            for k in range(c):
                j = idx[i, k]
                diff[k, 0] = points[j, 0] - m0
                diff[k, 1] = points[j, 1] - m1
                diff[k, 2] = points[j, 2] - m2
                for a in range(3):
                    for b in range(3):
                        cov[a, b] += diff[k, a] * diff[k, b]
            _, vec = np.linalg.eigh(cov)
            for a in range(3):
                fr[a, 0] = vec[a, 2]
                fr[a, 1] = vec[a, 1]
            for ax in range(2):
                s = _sign_by_skew(diff, c, fr, ax)
                for a in range(3):
                    fr[a, ax] *= s
            fr[0, 2] = fr[1, 0] * fr[2, 1] - fr[2, 0] * fr[1, 1]
            fr[1, 2] = fr[2, 0] * fr[0, 1] - fr[0, 0] * fr[2, 1]
            fr[2, 2] = fr[0, 0] * fr[1, 1] - fr[1, 0] * fr[0, 1]
            for a in range(3):
                for b in range(3):
                    frames[i, a, b] = fr[a, b]
            # the quadric w = a u² + b uv + c v² + d u + e v + f in the frame
            for a in range(6):
                rhs[a] = 0.0
                for b in range(6):
                    M[a, b] = 0.0
            for k in range(c):
                j = idx[i, k]
                e0 = points[j, 0] - points[i, 0]
                e1 = points[j, 1] - points[i, 1]
                e2 = points[j, 2] - points[i, 2]
                for a in range(3):
                    loc[k, a] = e0 * fr[0, a] + e1 * fr[1, a] + e2 * fr[2, a]
                u = loc[k, 0] / r
                v = loc[k, 1] / r
                z = loc[k, 2] / r
                row[0] = u * u
                row[1] = u * v
                row[2] = v * v
                row[3] = u
                row[4] = v
                row[5] = 1.0
                for a in range(6):
                    rhs[a] += row[a] * z
                    for b in range(a + 1):
                        M[a, b] += row[a] * row[b]
            tr = 0.0
            for a in range(6):
                tr += M[a, a]
                for b in range(a):
                    M[b, a] = M[a, b]
            tr = max(tr, 1.0)
            _chol_solve(M, sel, 6, 1e-9 * tr, L, rhs, q)
            g2 = 1.0 + q[3] * q[3] + q[4] * q[4]
            gauss[i] = (4.0 * q[0] * q[2] - q[1] * q[1]) / (g2 * g2) / (r * r)
            total[i] = 2.0 * np.sqrt(q[0] * q[0] + q[2] * q[2] + 0.5 * q[1] * q[1]) / r
            # ray atoms: the neighbour nearest each ray end in the tangent plane
            for m in range(n_rays):
                best = np.inf
                kb = 0
                for k in range(c):
                    u = loc[k, 0]
                    v = loc[k, 1]
                    d2 = u * u + v * v - 2.0 * (u * ends[m, 0] + v * ends[m, 1])
                    if d2 < best:
                        best = d2
                        kb = k
                atoms[i, m] = idx[i, kb]

    @_jit(inline="always")
    def _sym3_eig_into(a00, a01, a02, a11, a12, a22, lam, nrm, c, s):
        """λ0 ≤ λ1 ≤ λ2 (clipped at 0) and the unit eigenvector of λ0 of one
        symmetric 3×3 matrix, written to lam[c, s] and nrm[c, s]; the closed
        form of ``multiscale.sym3_eig``, step for step."""
        q = (a00 + a11 + a22) / 3.0
        p1 = a01 * a01 + a02 * a02 + a12 * a12
        b00, b11, b22 = a00 - q, a11 - q, a22 - q
        p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
        p = np.sqrt(p2 / 6.0)
        safe = p if p > 0 else 1.0
        det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
               + a02 * (a01 * a12 - b11 * a02))
        r = min(max(det / (2.0 * safe ** 3), -1.0), 1.0)
        phi = np.arccos(r) / 3.0
        l2 = q + 2.0 * p * np.cos(phi)
        l0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
        l1 = 3.0 * q - l2 - l0
        x0, x1, x2 = max(l0, 0.0), max(l1, 0.0), max(l2, 0.0)
        if x0 > x1:
            x0, x1 = x1, x0
        if x1 > x2:
            x1, x2 = x2, x1
        if x0 > x1:
            x0, x1 = x1, x0
        lam[c, s, 0], lam[c, s, 1], lam[c, s, 2] = x0, x1, x2
        m00, m11, m22 = a00 - l0, a11 - l0, a22 - l0
        best = -1.0
        v0 = v1 = v2 = 0.0
        for t in range(3):
            if t == 0:    # r0 × r1
                y0 = a01 * a12 - a02 * m11
                y1 = a02 * a01 - m00 * a12
                y2 = m00 * m11 - a01 * a01
            elif t == 1:  # r0 × r2
                y0 = a01 * m22 - a02 * a12
                y1 = a02 * a02 - m00 * m22
                y2 = m00 * a12 - a01 * a02
            else:         # r1 × r2
                y0 = m11 * m22 - a12 * a12
                y1 = a12 * a02 - a01 * m22
                y2 = a01 * a12 - m11 * a02
            cn = y0 * y0 + y1 * y1 + y2 * y2
            if cn > best:
                best, v0, v1, v2 = cn, y0, y1, y2
        vn = np.sqrt(best)
        if vn > 0:
            nrm[c, s, 0], nrm[c, s, 1], nrm[c, s, 2] = v0 / vn, v1 / vn, v2 / vn
        else:
            nrm[c, s, 0], nrm[c, s, 1], nrm[c, s, 2] = 0.0, 0.0, 1.0

    @_jit()
    def scale_moments(points, idx, rows, ks, corr):
        """Centroid, covariance eigenvalues and normal of every row's first
        ks[s] neighbours, for every scale s: running sums of the offsets
        x = points[idx[c, j]] − points[rows[c]] and of x xᵀ along the sorted
        neighbour list (``multiscale.scale_moments``).  The offsets are read
        from the cloud, not from a gathered (c, k, 3) array."""
        c_n, k_n = idx.shape[0], idx.shape[1]
        n_s = len(ks)
        mean = np.empty((c_n, n_s, 3))
        lam = np.empty((c_n, n_s, 3))
        nrm = np.empty((c_n, n_s, 3))
        for c in range(c_n):
            r = rows[c]
            p0, p1, p2 = points[r, 0], points[r, 1], points[r, 2]
            s0 = s1 = s2 = 0.0
            q00 = q01 = q02 = q11 = q12 = q22 = 0.0
            s = 0
            for j in range(k_n):
                q = idx[c, j]
                y0, y1, y2 = points[q, 0] - p0, points[q, 1] - p1, points[q, 2] - p2
                s0 += y0
                s1 += y1
                s2 += y2
                q00 += y0 * y0
                q01 += y0 * y1
                q02 += y0 * y2
                q11 += y1 * y1
                q12 += y1 * y2
                q22 += y2 * y2
                if s < n_s and j + 1 == ks[s]:
                    kf = float(ks[s])
                    m0, m1, m2 = s0 / kf, s1 / kf, s2 / kf
                    mean[c, s, 0], mean[c, s, 1], mean[c, s, 2] = m0, m1, m2
                    f = corr[s]
                    _sym3_eig_into((q00 / kf - m0 * m0) * f, (q01 / kf - m0 * m1) * f,
                                   (q02 / kf - m0 * m2) * f, (q11 / kf - m1 * m1) * f,
                                   (q12 / kf - m1 * m2) * f, (q22 / kf - m2 * m2) * f,
                                   lam, nrm, c, s)
                    s += 1
        return mean, lam, nrm

    @_jit()
    def strip_extent_rows(points, idx, rows, mean, normal, h, half, gap, out):
        """Rows of ``_border.strip_extent_at``: per point the projections (in h)
        on the border direction u of the neighbours within ``half`` of the line
        along u, sorted, up to the first empty stretch > ``gap``; offsets read
        from the cloud as in ``scale_moments``."""
        c_n, k_n = idx.shape[0], idx.shape[1]
        a = np.empty(k_n)
        for c in range(c_n):
            r = rows[c]
            p0, p1, p2 = points[r, 0], points[r, 1], points[r, 2]
            n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
            m0, m1, m2 = mean[c, 0], mean[c, 1], mean[c, 2]
            mn = m0 * n0 + m1 * n1 + m2 * n2
            t0, t1, t2 = m0 - mn * n0, m1 - mn * n1, m2 - mn * n2
            tl = max(np.sqrt(t0 * t0 + t1 * t1 + t2 * t2), 1e-300)
            u0, u1, u2 = -t0 / tl, -t1 / tl, -t2 / tl
            v0, v1, v2 = n1 * u2 - n2 * u1, n2 * u0 - n0 * u2, n0 * u1 - n1 * u0
            for j in range(k_n):
                q = idx[c, j]
                y0, y1, y2 = points[q, 0] - p0, points[q, 1] - p1, points[q, 2] - p2
                aj = (y0 * u0 + y1 * u1 + y2 * u2) / h
                bj = abs(y0 * v0 + y1 * v1 + y2 * v2) / h
                a[j] = aj if bj <= half and aj > 0.0 else 0.0
            a.sort()
            first = k_n - 1
            for j in range(k_n - 1):
                if a[j + 1] - a[j] > gap:
                    first = j
                    break
            out[c] = a[first]

    @_jit()
    def border_gap_rows(points, neighbours, out):
        """Rows of ``_border.border_gap``: per point the offsets of its
        neighbours (column 0 is the point), the smallest eigenvector of their
        centred scatter (``_sym3_eig_into``), the polar angles of the offsets
        in the plane orthogonal to it (the frame of
        ``_border.largest_angle_gap``), sorted, and the largest step between
        consecutive angles, the wrap-around one included."""
        c_n, k_n = neighbours.shape[0], neighbours.shape[1] - 1
        y = np.empty((k_n, 3))
        ang = np.empty(k_n)
        lam = np.empty((1, 1, 3))
        nrm = np.empty((1, 1, 3))
        for c in range(c_n):
            r = neighbours[c, 0]
            p0, p1, p2 = points[r, 0], points[r, 1], points[r, 2]
            s0 = s1 = s2 = 0.0
            for j in range(k_n):
                q = neighbours[c, j + 1]
                y0, y1, y2 = points[q, 0] - p0, points[q, 1] - p1, points[q, 2] - p2
                y[j, 0], y[j, 1], y[j, 2] = y0, y1, y2
                s0 += y0
                s1 += y1
                s2 += y2
            m0, m1, m2 = s0 / k_n, s1 / k_n, s2 / k_n
            a00 = a01 = a02 = a11 = a12 = a22 = 0.0
            for j in range(k_n):
                z0, z1, z2 = y[j, 0] - m0, y[j, 1] - m1, y[j, 2] - m2
                a00 += z0 * z0
                a01 += z0 * z1
                a02 += z0 * z2
                a11 += z1 * z1
                a12 += z1 * z2
                a22 += z2 * z2
            _sym3_eig_into(a00, a01, a02, a11, a12, a22, lam, nrm, 0, 0)
            n0, n1, n2 = nrm[0, 0, 0], nrm[0, 0, 1], nrm[0, 0, 2]
            if abs(n0) < 0.9:   # u = n × e_x, else n × e_y
                u0, u1, u2 = 0.0, n2, -n1
            else:
                u0, u1, u2 = -n2, 0.0, n0
            ul = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
            u0, u1, u2 = u0 / ul, u1 / ul, u2 / ul
            v0, v1, v2 = n1 * u2 - n2 * u1, n2 * u0 - n0 * u2, n0 * u1 - n1 * u0
            for j in range(k_n):
                y0, y1, y2 = y[j, 0], y[j, 1], y[j, 2]
                ang[j] = np.arctan2(y0 * v0 + y1 * v1 + y2 * v2, y0 * u0 + y1 * u1 + y2 * u2)
            ang.sort()
            best = 2.0 * np.pi - (ang[k_n - 1] - ang[0])
            for j in range(k_n - 1):
                best = max(best, ang[j + 1] - ang[j])
            out[c] = best
