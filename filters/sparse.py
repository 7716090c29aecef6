"""
sparse.py
---------
Sparse coding and dictionary learning (thesis ch.3): batched orthogonal
matching pursuit, batched Lasso by LARS (3.7) and K-SVD (Algorithm 3.3).

Signals are the *rows* of ``X`` (``(m, d)``) and atoms are the rows of the
dictionary ``D`` (``(n_atoms, d)``, unit norm), so a signal is approximated by
``codes @ D``.  Codes are returned as ``scipy.sparse.csr_matrix`` of shape
``(m, n_atoms)``: at a million signals a dense code matrix would take 1.6 GB.

The solvers are vectorised over signals (the many small problems share one
dictionary), which is what the point-cloud filters need: every point is a
signal of 7-40 features and there are up to 10^6 of them.  scikit-learn's
``orthogonal_mp_gram`` and ``sparse_encode(algorithm="lasso_lars")`` loop over
signals in Python.  Measured on this machine (2 shared cores, d = 7, 200
atoms): scikit-learn OMP (3 atoms) ≈ 100-150 µs per signal, ``omp`` below
≈ 6 µs (10^6 signals in 6 s); scikit-learn LassoLars ≈ 1.9 ms per signal
(≈ 30 min at 10^6), ``lasso_lars`` below ≈ 60 µs on the SDBS features
(2·10^5 signals in 12 s).  The tests check both against scikit-learn.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from dataclasses import dataclass

import numpy as np
from scipy import sparse as sp

from . import progress
from . import _kernels
from ._validation import InvalidParameterError, check_param, check_seed

log = logging.getLogger("pcprep")

try:  # installed with scikit-learn
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover
    threadpool_limits = None


def _single_blas():
    """The solvers' matrix products are skinny ((c, d≤40) × (d, S)); BLAS
    threads cost more than they bring there (3× slower measured on the shared
    2-core machine), so they run single-threaded."""
    if threadpool_limits is None:  # pragma: no cover
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")

#: signals per chunk in the batched solvers
CHUNK = 32_768
#: relative tolerance under which a correlation counts as zero
_EPS = 1e-12


# --------------------------------------------------------------------------- helpers
def _as_signals(X, func: str, name: str = "X") -> np.ndarray:
    try:
        arr = np.asarray(X, dtype=np.float64)  # read only here: no copy of float64 input
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{func}: {name} must be numeric") from exc
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InvalidParameterError(f"{func}: {name} must be a non-empty 2-D array, got {arr.shape}")
    # row chunks: no mask of the signals' size (a tiled run's SDBS features are
    # a memory map of every row, and its mask was 7 B per point on the driver)
    if not all(np.isfinite(arr[s0:s0 + CHUNK]).all() for s0 in range(0, len(arr), CHUNK)):
        raise InvalidParameterError(f"{func}: {name} contains NaN or Inf")
    return np.ascontiguousarray(arr)


@dataclass(frozen=True)
class _RowChunks:
    """Consecutive chunks of the signals ``X`` or of ``X[rows]``."""

    X: np.ndarray
    rows: np.ndarray | None

    def __call__(self, s0: int, e: int) -> np.ndarray:
        if self.rows is None:
            return self.X[s0:e]
        return self.X[self.rows[s0:e]]


def _row_chunks(X: np.ndarray, rows, func: str) -> _RowChunks:
    if rows is None:
        return _RowChunks(X, None)
    rows = np.asarray(rows)
    if rows.ndim != 1 or (rows.size and (rows.dtype.kind not in "iu" or rows.min() < 0
                                         or rows.max() >= len(X))):
        raise InvalidParameterError(
            f"{func}: rows must be a 1-D array of row indices in [0, {len(X)})")
    return _RowChunks(X, rows.astype(np.int64, copy=False))


def _as_dictionary(D, d: int, func: str) -> np.ndarray:
    D = _as_signals(D, func, "D")
    if D.shape[1] != d:
        raise InvalidParameterError(
            f"{func}: D has {D.shape[1]} columns but the signals have {d}")
    norm = np.linalg.norm(D, axis=1)
    if (norm < 1e-12).any():
        raise InvalidParameterError(f"{func}: D has zero atoms")
    return D / norm[:, None]


def _csr(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, shape) -> sp.csr_matrix:
    keep = vals != 0.0
    return sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=shape)


def _compact(s0: int, sup: np.ndarray, coef: np.ndarray):
    """Non-zero entries of one chunk's padded (c, L) codes as int32 row / column
    indices and values (keeps the 10^6-signal assembly small)."""
    c, L = sup.shape
    nz = coef != 0.0
    r = np.broadcast_to(np.arange(s0, s0 + c, dtype=np.int32)[:, None], (c, L))[nz]
    return r, sup[nz].astype(np.int32), coef[nz]


def code_length(codes, X, D) -> tuple[np.ndarray, np.ndarray]:
    """Sparsity and residual of every signal, the two MDL code lengths of
    thesis §6.3.3 / (6.5)-(6.7).

    Parameters
    ----------
    codes : (m, n_atoms) sparse or dense
    X : (m, d) float
    D : (n_atoms, d) float

    Returns
    -------
    nnz : (m,) int
        ``‖α_j‖₀`` (6.5)-(6.6).
    residual : (m,) float
        ``‖x_j − α_j D‖₂`` (6.7).
    """
    codes = sp.csr_matrix(codes)
    codes.eliminate_zeros()
    nnz = np.diff(codes.indptr).astype(np.int64)
    X = np.asarray(X, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    # by row chunks: the reconstruction is never held for every signal at once
    residual = np.empty(len(X))  # noqa: NPY-empty -- every chunk written below
    for s0 in range(0, len(X), CHUNK):
        e = min(len(X), s0 + CHUNK)
        residual[s0:e] = np.linalg.norm(X[s0:e] - codes[s0:e] @ D, axis=1)
    return nnz, residual


# --------------------------------------------------------------------------- OMP
def _omp_chunk(X, D, L, tol):
    """Batched OMP on one chunk; returns (support (c, L) int, coef (c, L))."""
    c, d = X.shape
    sup = np.zeros((c, L), dtype=np.int64)
    coef = np.zeros((c, L))
    live = np.ones(c, dtype=bool)
    R = X.copy()
    xnorm2 = np.einsum("ij,ij->i", X, X)
    if tol is not None:
        live &= xnorm2 > tol
    G = D @ D.T
    XD = X @ D.T  # (c, S) correlations of the signals
    rows_all = np.arange(c)
    for t in range(L):
        rows = rows_all[live]
        if rows.size == 0:
            break
        corr = np.abs(R[rows] @ D.T)
        if t:
            np.put_along_axis(corr, sup[rows, :t], -1.0, axis=1)
        j = np.argmax(corr, axis=1)
        cmax = corr[np.arange(rows.size), j]
        scale = np.sqrt(xnorm2[rows]) + 1e-300
        ok = cmax > _EPS * scale  # residual already orthogonal to every atom
        live[rows[~ok]] = False
        rows, j = rows[ok], j[ok]
        if rows.size == 0:
            break
        sup[rows, t] = j
        s = sup[rows, : t + 1]
        Gs = G[s[:, :, None], s[:, None, :]] + 1e-12 * np.eye(t + 1)
        b = np.take_along_axis(XD[rows], s, axis=1)
        a = np.linalg.solve(Gs, b[:, :, None])[:, :, 0]
        coef[rows, : t + 1] = a
        R[rows] = X[rows] - np.einsum("ck,ckd->cd", a, D[s])
        if tol is not None:
            done = np.einsum("ij,ij->i", R[rows], R[rows]) <= tol
            live[rows[done]] = False
    return sup, coef


def _omp_codes(X, D, L, tol):
    """Padded OMP codes (support (c, L), coef (c, L)) of one chunk, by the
    compiled kernel or the NumPy solver."""
    if _kernels.ENABLED:
        G = np.ascontiguousarray(D @ D.T)
        X, D = np.ascontiguousarray(X), np.ascontiguousarray(D)
        parts = _kernels.run_chunks(lambda s, e: _kernels.omp_batch(
            X[s:e], D, G, int(L), float(tol or 0.0), tol is not None, _EPS), len(X),
            _kernels.TASK_ROWS)
        return _kernels.stack_parts(parts, 2)
    return _omp_chunk(X, D, L, tol)


def omp(X, D, *, n_nonzero_coefs: int | None = None, tol: float | None = None,
        rows: np.ndarray | None = None) -> sp.csr_matrix:
    """Orthogonal matching pursuit of many signals at once (problem (3.6)).

    Parameters
    ----------
    X : (m, d) float
        Signals, one per row.
    D : (n_atoms, d) float
        Dictionary, one atom per row; rows are normalised to unit length.
    n_nonzero_coefs : int, optional
        Maximum number of atoms per signal.  Default: ``max(1, d // 10)`` when
        ``tol`` is None, else ``min(d, n_atoms)``.
    tol : float, optional
        Stop a signal once its squared residual ``‖x − αD‖²`` is ≤ ``tol``
        (scikit-learn's convention).  With both given, whichever comes first.
    rows : (r,) int, optional
        Code only the signals ``X[rows]`` (gathered chunk by chunk, so no copy
        of the selected signals is made); the result then has r rows.

    Returns
    -------
    codes : (m, n_atoms) or (r, n_atoms) scipy.sparse.csr_matrix
        Coefficients on the (normalised) atoms of ``D``.

    Notes
    -----
    Each pursuit step is one vectorised operation over a chunk of signals:
    correlations with the residual, argmax, then all the small least-squares
    problems on the supports solved by one batched ``np.linalg.solve`` of the
    Gram sub-matrices.  Equal to scikit-learn's ``orthogonal_mp_gram`` up to
    ties (tested).
    """
    func = "omp"
    X = _as_signals(X, func)
    m, d = X.shape
    D = _as_dictionary(D, d, func)
    S = D.shape[0]
    if tol is not None:
        tol = check_param(tol, func=func, name="tol", kind=float, low=0.0)
    if n_nonzero_coefs is None:
        L = max(1, d // 10) if tol is None else min(d, S)
    else:
        L = check_param(n_nonzero_coefs, func=func, name="n_nonzero_coefs", kind=int,
                        low=1, high=min(d, S))
    take = _row_chunks(X, rows, func)
    m = len(X) if rows is None else len(take.rows)
    out_r, cols, vals = [], [], []
    with _single_blas(), progress.step("OMP coding", m) as advance:
        for s0 in range(0, m, CHUNK):
            e = min(m, s0 + CHUNK)
            r, c_, v = _compact(s0, *_omp_codes(take(s0, e), D, L, tol))
            out_r.append(r)
            cols.append(c_)
            vals.append(v)
            advance(e - s0)
    return _csr(np.concatenate(out_r), np.concatenate(cols), np.concatenate(vals), (m, S))


# --------------------------------------------------------------------------- LARS
def _lars_chunk(X, D, alpha, K, max_steps, cand=None):
    """Batched LARS with the Lasso modification (Efron et al. 2004) on one chunk.

    Minimises ½‖x − βD‖² + alpha‖β‖₁ for every row x of X over the atoms
    ``cand`` (c, T) of each row (global atom ids; default all atoms).  The
    active set of each signal is held in a padded index array ``act`` (c, K)
    with ``nact`` valid entries (padded slots repeat the first active atom);
    padded slots carry an identity block so one batched solve serves signals
    with active sets of different sizes.  Correlations are recomputed from the
    residual in signal space.
    """
    c, d = X.shape
    S = D.shape[0]
    if cand is None:
        cand = np.broadcast_to(np.arange(S), (c, S))
    T = cand.shape[1]
    G = D @ D.T
    Dc32 = D.astype(np.float32)[cand]  # (c, T, d)
    beta_act = np.zeros((c, K))
    R = X.copy()
    cor0 = np.einsum("ctd,cd->ct", D[cand], X)
    p0 = np.argmax(np.abs(cor0), axis=1)
    j0 = cand[np.arange(c), p0]
    lam = np.abs(cor0[np.arange(c), p0])
    del cor0
    live = lam > alpha
    act = np.repeat(j0[:, None], K, axis=1)
    pos = np.repeat(p0[:, None], K, axis=1)  # candidate positions of the active atoms
    blocked_all = np.zeros((c, T), dtype=bool)  # active (or just dropped) candidates
    blocked_all[np.arange(c), p0] = True
    nact = np.ones(c, dtype=np.int64)
    slot = np.arange(K)
    eye = np.eye(K)
    last_drop = np.full(c, -1)  # candidate position of an atom that just left: it
    # may not re-enter at γ = 0
    for _ in range(max_steps):
        rows = np.flatnonzero(live)
        if rows.size == 0:
            break
        nr = rows.size
        ar = np.arange(nr)
        a_idx = act[rows]
        na = nact[rows]
        valid = slot[None, :] < na[:, None]
        Rr = R[rows]
        lam_r = lam[rows]
        Da = D[a_idx]  # (nr, K, d)
        s_act = np.sign(np.einsum("ckd,cd->ck", Da, Rr)) * valid
        Gs = G[a_idx[:, :, None], a_idx[:, None, :]]
        Gs *= valid[:, :, None] & valid[:, None, :]
        Gs += np.where(valid, 1e-12, 1.0)[:, :, None] * eye
        w = np.linalg.solve(Gs, s_act[:, :, None])[:, :, 0] * valid
        # correlation change per unit step: a = G[:, A] w = D (D_A^T w)
        u = np.einsum("ck,ckd->cd", w, Da)
        # joining: |c_j − γ a_j| = λ − γ.  The candidate atom is *selected* in
        # float32 (these (c, T) passes dominate the cost); its step is then
        # recomputed in float64.  For inactive j both numerators are positive,
        # so a non-positive denominator means "never".
        Dr = Dc32[rows]
        cor32 = np.matmul(Dr, Rr.astype(np.float32)[:, :, None])[:, :, 0]
        a32 = np.matmul(Dr, u.astype(np.float32)[:, :, None])[:, :, 0]
        lam32 = lam_r.astype(np.float32)[:, None]
        g1 = lam32 - cor32
        den = 1.0 - a32
        np.maximum(den, 1e-30, out=den)
        np.divide(g1, den, out=g1)
        np.add(cor32, lam32, out=cor32)
        np.add(a32, 1.0, out=a32)
        np.maximum(a32, 1e-30, out=a32)
        np.divide(cor32, a32, out=cor32)
        np.minimum(g1, cor32, out=g1)
        g1[blocked_all[rows]] = np.inf
        g1[na >= K] = np.inf
        pj = np.argmin(g1, axis=1)
        ok = np.isfinite(g1[ar, pj])
        del g1, den, cor32, a32
        jj = cand[rows, pj]
        Dj = D[jj]
        cj = np.einsum("cd,cd->c", Rr, Dj)
        aj = np.einsum("cd,cd->c", u, Dj)
        with np.errstate(divide="ignore", invalid="ignore"):
            gj1 = np.where(aj < 1.0, (lam_r - cj) / (1.0 - aj), np.inf)
            gj2 = np.where(aj > -1.0, (lam_r + cj) / (1.0 + aj), np.inf)
        g_join = np.where(ok, np.maximum(np.minimum(gj1, gj2), 0.0), np.inf)
        tiny = 1e-12 * lam_r[:, None]
        # dropping: β_k + γ w_k = 0
        b = beta_act[rows]
        with np.errstate(divide="ignore", invalid="ignore"):
            gd = -b / w
        gd = np.where(valid & (w != 0) & np.isfinite(gd) & (gd > tiny), gd, np.inf)
        kk = np.argmin(gd, axis=1)
        g_drop = gd[ar, kk]
        g_end = lam_r - alpha
        gamma = np.minimum(np.minimum(g_join, g_drop), g_end)
        # advance
        beta_act[rows] = b + gamma[:, None] * w
        R[rows] = Rr - gamma[:, None] * u
        lam[rows] = lam_r - gamma
        end = gamma >= g_end
        live[rows[end]] = False
        drop = ~end & (g_drop <= g_join)
        join = ~end & ~drop
        js = np.flatnonzero(join)
        if js.size:
            # an atom in the span of the active ones (a duplicate, say) cannot
            # join: its pivot 1 − g_Aᵀ G_AA⁻¹ g_A vanishes.  Its correlation
            # stays tied with theirs, so the path goes on without it; it is
            # blocked for good and the step is not an event.
            gA = G[a_idx[js], jj[js][:, None]] * valid[js]
            z = np.linalg.solve(Gs[js], gA[:, :, None])[:, :, 0]
            piv = G[jj[js], jj[js]] + 1e-12 - np.einsum("ck,ck->c", gA, z)
            bad = js[piv < 1e-10]
            if bad.size:
                blocked_all[rows[bad], pj[bad]] = True
                join[bad] = False
        r = rows[join]
        ld = last_drop[r]
        has = ld >= 0
        blocked_all[r[has], ld[has]] = False  # the dropped atom may re-enter later
        last_drop[r] = -1
        act[r, nact[r]] = jj[join]
        pos[r, nact[r]] = pj[join]
        blocked_all[r, pj[join]] = True
        beta_act[r, nact[r]] = 0.0
        nact[r] += 1
        r, k = rows[drop], kk[drop]
        if r.size:
            # move the last active slot into the dropped one; the dropped atom
            # stays blocked until the next event
            ld = last_drop[r]
            has = ld >= 0
            blocked_all[r[has], ld[has]] = False
            last = nact[r] - 1
            last_drop[r] = pos[r, k]
            act[r, k] = act[r, last]
            pos[r, k] = pos[r, last]
            beta_act[r, k] = beta_act[r, last]
            beta_act[r, last] = 0.0
            act[r, last] = act[r, 0]
            pos[r, last] = pos[r, 0]
            nact[r] = last
    else:
        n_live = int(live.sum())
        if n_live:
            log.warning("lasso_lars: %d signal(s) hit max_steps", n_live)
    valid = slot[None, :] < nact[:, None]
    return act, np.where(valid, beta_act, 0.0)


#: atoms screened per signal before LARS (by |d_j·x|); KKT violators are redone
#: with every atom, so the result does not depend on it
SCREEN = 48


def _lasso_chunk(X, D, alpha, K, max_steps):
    S = D.shape[0]
    if _kernels.ENABLED:
        G = np.ascontiguousarray(D @ D.T)
        X, D = np.ascontiguousarray(X), np.ascontiguousarray(D)
        parts = _kernels.run_chunks(lambda s, e: _kernels.lars_batch(
            X[s:e], D, G, float(alpha), int(K), int(max_steps)), len(X),
            _kernels.TASK_ROWS)
        act, beta = _kernels.stack_parts(parts, 2)
        n_hit = sum(q[2] for q in parts)
        if n_hit:
            log.warning("lasso_lars: %d signal(s) hit max_steps", n_hit)
        return act, beta
    if S <= 64:
        return _lars_chunk(X, D, alpha, K, max_steps)
    corr = -np.abs(X.astype(np.float32) @ D.T.astype(np.float32))
    cand = np.argpartition(corr, SCREEN - 1, axis=1)[:, :SCREEN]
    del corr
    act, beta = _lars_chunk(X, D, alpha, K, max_steps, cand=cand)
    # KKT on all atoms: |d_j·r| ≤ alpha everywhere
    R = X - np.einsum("ck,ckd->cd", beta, D[act])
    viol = np.flatnonzero(np.abs(R @ D.T).max(axis=1) > alpha * (1.0 + 1e-7))
    if viol.size:
        a2, b2 = _lars_chunk(X[viol], D, alpha, K, max_steps)
        act[viol], beta[viol] = a2, b2
    log.info("lasso_lars: %d of %d signals re-solved with every atom", viol.size, len(X))
    return act, beta


def lasso_lars(X, D, *, alpha: float, max_steps: int | None = None,
               rows: np.ndarray | None = None) -> sp.csr_matrix:
    """Lasso codes of many signals by LARS (thesis (3.7), Algorithm 3.1 with
    the Lasso modification).

    Parameters
    ----------
    X : (m, d) float
        Signals, one per row.
    D : (n_atoms, d) float
        Dictionary, one atom per row; rows are normalised to unit length.
    alpha : float
        Weight of the ℓ1 term in ``½‖x − αD‖₂² + alpha‖α‖₁`` (the SPAMS /
        scikit-learn ``sparse_encode`` convention; the thesis' (3.7) has no ½,
        so its λ equals ``2 * alpha``).  ``alpha ≥ max_j |d_j·x|`` gives α = 0.
    max_steps : int, optional
        Cap on LARS events (joins and drops) per signal; default ``8 * min(d, n_atoms)``.
    rows : (r,) int, optional
        Code only the signals ``X[rows]`` (as in ``omp``).

    Returns
    -------
    codes : (m, n_atoms) or (r, n_atoms) scipy.sparse.csr_matrix

    Notes
    -----
    All signals follow their own regularisation paths in lock-step: one
    vectorised LARS event (an atom joins or leaves the active set, or the path
    reaches ``alpha``) per iteration for every unfinished signal.  The active
    set never exceeds ``min(d, n_atoms)`` atoms.  With more than 64 atoms each
    signal first runs on its 48 atoms most correlated with it (``SCREEN``);
    the optimality (KKT) conditions are then checked against every atom and
    the signals that violate them (about 5 % on the SDBS features) are solved
    again with the whole dictionary, so the answer does not depend on the
    screening.  Matches scikit-learn's
    ``Lasso`` (coordinate descent, ``alpha/d`` in its scaling) to solver
    precision (tested).  Degenerate dictionaries are handled: an atom equal
    (up to sign) to an earlier one gets no coefficient, and an atom in the
    span of the active ones does not join the active set (its Cholesky pivot
    vanishes).
    """
    func = "lasso_lars"
    X = _as_signals(X, func)
    m, d = X.shape
    D = _as_dictionary(D, d, func)
    S = D.shape[0]
    alpha = check_param(alpha, func=func, name="alpha", kind=float, low=0.0, closed="neither")
    # an atom equal to an earlier one up to sign adds nothing to the Lasso
    # (the earlier one can carry its coefficient) and would tie with it along
    # the whole path: it is left out
    cos = np.abs(D @ D.T)
    atoms = np.flatnonzero(~np.triu(cos > 1.0 - 1e-9, k=1).any(axis=0))
    Du = D[atoms] if atoms.size < S else D
    K = min(d, len(Du))
    if max_steps is None:
        max_steps = 8 * K
    max_steps = check_param(max_steps, func=func, name="max_steps", kind=int, low=1)
    take = _row_chunks(X, rows, func)
    m = len(X) if rows is None else len(take.rows)
    out_r, cols, vals = [], [], []
    with _single_blas(), progress.step("LARS-Lasso coding", m) as advance:
        for s0 in range(0, m, CHUNK):
            e = min(m, s0 + CHUNK)
            act, beta = _lasso_chunk(take(s0, e), Du, alpha, K, max_steps)
            r, c_, v = _compact(s0, atoms[act], beta)
            out_r.append(r)
            cols.append(c_)
            vals.append(v)
            advance(e - s0)
    return _csr(np.concatenate(out_r), np.concatenate(cols), np.concatenate(vals), (m, S))


# --------------------------------------------------------------------------- K-SVD
@dataclass(frozen=True)
class KSVDResult:
    """Result of ``ksvd``.

    Attributes
    ----------
    dictionary : (n_atoms, d) float
        Learned atoms, unit-norm rows.
    codes : (m, n_atoms) scipy.sparse.csr_matrix
        OMP codes of *all* the signals on the final dictionary (of the
        training signals only, ``(len(train_idx), n_atoms)``, when
        ``code_all=False``).
    errors : (n_iter,) float
        Root-mean-square residual of the training signals after each iteration's
        coding stage.
    train_idx : (m_train,) int
        Rows of ``X`` used for training (all rows when m ≤ ``max_train``).
    """

    dictionary: np.ndarray
    codes: sp.csr_matrix
    errors: np.ndarray
    train_idx: np.ndarray


def _update_atoms(Xt, D, sup, coef, rng):
    """K-SVD dictionary-update stage (Alg. 3.3 lines 5-12) on dense small codes.

    ``sup``/``coef`` (m, L) hold each training signal's support and
    coefficients; they are updated in place together with D.
    """
    S = D.shape[0]
    recon = np.einsum("ml,mld->md", coef, D[sup])
    E_all = Xt - recon
    flat = sup.ravel()
    nz = coef.ravel() != 0
    order = np.argsort(flat[nz], kind="stable")
    pos = np.flatnonzero(nz)[order]  # flat positions grouped by atom
    starts = np.searchsorted(flat[nz][order], np.arange(S + 1))
    if _kernels.ENABLED:
        used = _kernels.ksvd_update(D, sup, coef, E_all, pos.astype(np.int64),
                                    starts.astype(np.int64))
        unused = np.flatnonzero(~used).tolist()
    else:
        unused = _update_atoms_numpy(D, sup, coef, E_all, pos, starts)
    # like Elad's K-SVD toolbox ("clear dictionary"): an atom nearly equal to
    # another one (|cos| > 0.99) is wasted as well
    cos = np.abs(D @ D.T)
    np.fill_diagonal(cos, 0.0)
    dup = np.flatnonzero(np.triu(cos > 0.99).any(axis=0))
    unused = sorted(set(unused) | set(dup.tolist()))
    if unused:
        # replace unused atoms by the worst-represented training signals
        err = np.einsum("ij,ij->i", E_all, E_all)
        worst = np.argsort(-err, kind="stable")[: len(unused)]
        for j, w in zip(unused, worst):
            v = Xt[w]
            nv = np.linalg.norm(v)
            D[j] = v / nv if nv > 1e-12 else rng.standard_normal(D.shape[1])
            D[j] /= np.linalg.norm(D[j])
    return len(unused)


def _update_atoms_numpy(D, sup, coef, E_all, pos, starts):
    """Atom loop of ``_update_atoms`` in NumPy (reference / no-numba path);
    returns the unused atoms."""
    S = D.shape[0]
    unused = []
    for j in range(S):  # loop over atoms (Alg. 3.3 line 5)
        p = pos[starts[j]:starts[j + 1]]
        if p.size == 0:
            unused.append(j)
            continue
        r, slot = np.divmod(p, sup.shape[1])
        # E_j restricted to ω_j: residual with atom j's contribution put back
        Ej = E_all[r] + coef[r, slot][:, None] * D[j][None, :]
        # rank-1 SVD via the (d × d) scatter matrix: d_j = top eigenvector
        ev, evec = np.linalg.eigh(Ej.T @ Ej)
        dj = evec[:, -1]
        if dj @ D[j] < 0:
            dj = -dj
        new = Ej @ dj
        D[j] = dj
        coef[r, slot] = new
        E_all[r] = Ej - new[:, None] * dj[None, :]
    return unused


def content_keys(X: np.ndarray, seed: int | None = 0, decimals: int = 6) -> np.ndarray:
    """A 64-bit hash of each row of ``X`` that depends on its content only.

    Each row is rounded to ``decimals`` decimals and hashed (splitmix64 over
    the columns, started from ``seed``).  Rows are hashed in chunks, so the
    memory beyond the (m,) result is one chunk; the key of a row does not
    depend on the other rows, so keys computed piece by piece (tiles) are the
    keys of the whole.
    """
    X = np.asarray(X, dtype=np.float64)
    keys = np.empty(len(X), dtype=np.uint64)  # noqa: NPY-empty -- every entry written below
    with np.errstate(over="ignore"):  # the products wrap modulo 2**64 on purpose
        start = np.uint64(0x9E3779B97F4A7C15) * np.uint64((seed or 0) + 1)
    for s0 in range(0, len(X), CHUNK):
        q = np.round(X[s0:s0 + CHUNK] * 10.0 ** decimals)
        q = np.clip(q, -2.0**62, 2.0**62).astype(np.int64).view(np.uint64)
        with np.errstate(over="ignore"):
            h = np.full(len(q), start, dtype=np.uint64)
            for j in range(q.shape[1]):
                h = h ^ q[:, j]
                h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
                h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
                h = h ^ (h >> np.uint64(31))
        keys[s0:s0 + len(q)] = h
    return keys


def content_order(X: np.ndarray, seed: int | None = 0, decimals: int = 6) -> np.ndarray:
    """A permutation of the rows of ``X`` that depends on their content only.

    The rows sorted by ``content_keys`` (stable): a pseudo-random order that
    does not change when the rows are permuted, nor when their values move by
    rounding noise (a rotated cloud's features), so a subsample taken as its
    first rows is the same set.
    """
    return np.argsort(content_keys(X, seed, decimals), kind="stable")


def first_in_order(keys: np.ndarray, m: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")[:m]`` without sorting every key: the
    m-th smallest key found by selection (O(n)), then only the keys up to it
    sorted (stably, from ascending row numbers, so ties keep row order).  The
    driver of a tiled run picks the training rows of a cloud of any size so."""
    keys = np.asarray(keys)
    if m >= len(keys):
        return np.argsort(keys, kind="stable")
    if m <= 0:
        return np.empty(0, dtype=np.int64)
    kth = np.partition(keys, m - 1)[m - 1]
    cand = np.flatnonzero(keys <= kth)
    return cand[np.argsort(keys[cand], kind="stable")[:m]]


class FirstInOrder:
    """``first_in_order`` of a key array fed chunk by chunk: ``add(keys,
    start)`` takes the keys of rows ``start:start + len(keys)`` (from any
    thread, chunks in any order), ``rows()`` gives
    ``np.argsort(all keys, kind="stable")[:m]``.

    Each chunk keeps its own m first rows, which are merged into the m first
    so far by (key, row): the stable sort's order, since it breaks ties by
    row.  So the memory is 2m keys and rows, not one key per row of the
    cloud and its partition's copy (16 B per row in the driver of a tiled
    run).  For m above ``MERGE_MAX`` the merges would sort more than they
    save, so the chunks are kept and selected from whole."""

    #: the largest m merged chunk by chunk
    MERGE_MAX = 1 << 20

    def __init__(self, m: int):
        self.m = int(m)
        self._keys = self._rows = None
        self._parts: list = []
        self._lock = threading.Lock()

    def add(self, keys: np.ndarray, start: int) -> None:
        keys = np.asarray(keys)
        if self.m > self.MERGE_MAX:
            with self._lock:
                self._parts.append((start, keys))
            return
        local = first_in_order(keys, self.m)
        k, r = keys[local], local + start
        with self._lock:
            if self._keys is not None:
                k, r = np.concatenate([self._keys, k]), np.concatenate([self._rows, r])
                order = np.lexsort((r, k))[:self.m]
                k, r = k[order], r[order]
            self._keys, self._rows = k, r

    def rows(self) -> np.ndarray:
        if self._parts:
            self._parts.sort(key=lambda part: part[0])
            return first_in_order(np.concatenate([p[1] for p in self._parts]), self.m)
        return np.empty(0, np.int64) if self._rows is None else self._rows.astype(np.int64)


def ksvd(X, n_atoms: int, *, n_nonzero_coefs: int | None = None, tol: float | None = None,
         max_iter: int = 10, max_train: int = 20_000, seed: int | None = None,
         code_all: bool = True, order=None) -> KSVDResult:
    """K-SVD dictionary learning (Aharon, Elad & Bruckstein 2006; thesis Alg. 3.3).

    Parameters
    ----------
    X : (m, d) float
        Training signals, one per row.
    n_atoms : int
        Dictionary size S.
    n_nonzero_coefs : int, optional
        Sparsity of the OMP coding stage (``k0`` of Alg. 3.3).  Default
        ``max(1, d // 10)`` when ``tol`` is None.
    tol : float, optional
        Squared-residual target of the OMP coding stage, per signal.
    max_iter : int, default=10
        Coding / update iterations.
    max_train : int, default=20000
        At most this many signals (a seeded random subsample) train the
        dictionary; all ``m`` signals are then coded on it.
    seed : int, optional
        Seeds the subsample and the initial dictionary.
    code_all : bool, default=True
        Code all ``m`` signals on the final dictionary; when False, ``codes``
        holds the training signals' codes only (rows in ``train_idx`` order),
        for callers that code with another solver afterwards.
    order : (m,) int or "rows", optional
        The order in which the signals are sampled and used: ``"rows"`` for a
        seeded random subsample in row order, or a permutation of
        ``range(m)`` that depends on the signals, not on their row order; the
        first ``max_train`` are the training subsample.  Default:
        ``content_order(X, seed)``.  With it, permuting the rows of ``X`` does
        not change the dictionary.

    Returns
    -------
    KSVDResult

    Notes
    -----
    Initialisation: ``n_atoms`` distinct training signals chosen at random,
    normalised (a zero signal is replaced by a random direction; if there are
    fewer signals than atoms the rest are random unit vectors).  After each
    update stage, atoms used by no signal are replaced by the currently worst
    represented training signals.  The SVD of each restricted residual
    ``E_j^R`` (Alg. 3.3 line 10) is taken through the eigen-decomposition of the
    ``d × d`` matrix ``E_j^Rᵀ E_j^R`` (d ≤ 40 here), which gives the same
    ``u1`` and coefficients ``σ1 v1``.
    Training on a subsample is a deviation from the thesis, for speed at
    10^6 points; the dictionary of 200 atoms in ≤ 40 dimensions is learned
    well from 2·10^4 signals.
    """
    func = "ksvd"
    X = _as_signals(X, func)
    m, d = X.shape
    n_atoms = check_param(n_atoms, func=func, name="n_atoms", kind=int, low=1)
    max_iter = check_param(max_iter, func=func, name="max_iter", kind=int, low=1)
    max_train = check_param(max_train, func=func, name="max_train", kind=int, low=1)
    seed = check_seed(seed, func=func)
    code_all = check_param(code_all, func=func, name="code_all", kind=bool)
    if tol is not None:
        tol = check_param(tol, func=func, name="tol", kind=float, low=0.0)
    if n_nonzero_coefs is None:
        L = max(1, d // 10) if tol is None else min(d, n_atoms)
    else:
        L = check_param(n_nonzero_coefs, func=func, name="n_nonzero_coefs", kind=int,
                        low=1, high=min(d, n_atoms))
    rng = np.random.default_rng(seed)
    # the signals in an order of their own (not the caller's row order), so that
    # permuting the rows of X gives the same dictionary
    if isinstance(order, str) and order == "rows":  # a seeded subsample, row order
        train_idx = np.arange(m) if m <= max_train else np.sort(
            rng.choice(m, size=max_train, replace=False))
    else:
        train_idx = (first_in_order(content_keys(X, seed), max_train) if order is None
                     else np.asarray(order, np.int64)[:max_train])
    Xt = X[train_idx]
    mt = len(Xt)
    # initial dictionary: distinct random training signals, normalised
    pick = rng.permutation(mt)[: min(n_atoms, mt)]
    D = np.array(Xt[pick], dtype=np.float64)
    if len(D) < n_atoms:
        D = np.vstack([D, rng.standard_normal((n_atoms - len(D), d))])
    nrm = np.linalg.norm(D, axis=1)
    zero = nrm < 1e-12
    if zero.any():
        D[zero] = rng.standard_normal((int(zero.sum()), d))
        nrm[zero] = np.linalg.norm(D[zero], axis=1)
    D /= nrm[:, None]
    errors = []
    with _single_blas():
        _ksvd_iterate(Xt, D, L, tol, max_iter, rng, errors)
    codes = omp(X if code_all else Xt, D, n_nonzero_coefs=L, tol=tol)
    return KSVDResult(dictionary=D, codes=codes, errors=np.asarray(errors), train_idx=train_idx)


def _ksvd_iterate(Xt, D, L, tol, max_iter, rng, errors):
    """Alternate OMP coding and the atom update (Alg. 3.3); D is updated in place."""
    mt = len(Xt)
    with progress.step("K-SVD dictionary", max_iter) as advance:
        for it in range(max_iter):
            _ksvd_step(Xt, D, L, tol, rng, errors, mt, it)
            advance()


def _ksvd_step(Xt, D, L, tol, rng, errors, mt, it):
    """One K-SVD iteration: code the training set, then update every atom."""
    sup, coef = [], []
    for s0 in range(0, mt, CHUNK):
        a, b = _omp_codes(Xt[s0:s0 + CHUNK], D, L, tol)
        sup.append(a)
        coef.append(b)
    sup, coef = np.concatenate(sup), np.concatenate(coef)
    resid = Xt - np.einsum("ml,mld->md", coef, D[sup])
    errors.append(float(np.sqrt(np.mean(np.einsum("ij,ij->i", resid, resid)))))
    n_unused = _update_atoms(Xt, D, sup, coef, rng)
    log.info("ksvd: iteration %d, rms residual %.4g, %d unused atom(s) replaced",
             it + 1, errors[-1], n_unused)
