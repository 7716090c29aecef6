"""
_denoise_jit.py
---------------
Compiled row kernels (numba) of :func:`pcprep.filters.denoise.denoise_l1_tv`:
one inner pass (energy (4.5), τ step (4.14), normal step (4.10)-(4.12), normal
variation (4.17) and the height fit), one pass of the n⁰ iteration (4.9), the
selection among neighbour normals, the smoothed curvature and the final
sphere projection.

Each kernel computes rows ``s:e`` of its pass, one point at a time, with the
same float64 arithmetic as its NumPy reference in ``_denoise_steps.py`` and
``_denoise_project.py`` (which runs when ``_kernels.ENABLED`` is False; the
tests compare the two), except that sums over a point's neighbours run as four
interleaved partial sums (``_sum4``) and the exponentials come from
``_exp_into`` (within 2 ulp of libm).  A point's neighbour terms are recomputed
from the positions instead of being gathered into (rows, k) arrays, which is
what the NumPy passes spend most of their time on, and they are computed in
branch-free loops over the neighbour count rounded up to 16 (``_up``), which
LLVM vectorises.  The kernels release the GIL, so the thread pool of
``_kernels.run_chunks`` runs them on every core.
"""

from __future__ import annotations

import numpy as np

import math

from ._denoise_kernels import GUARD, TAU_IRLS
from ._kernels import HAVE_NUMBA, _jit

#: exp's argument reduction x = n·ln 2 + r: log2(e), and ln 2 split so that
#: n·LN2_HI is exact for |n| < 2¹¹ (fdlibm's constants)
_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
#: 1.5·2⁵²: x·log2(e) + _SHIFT rounds x·log2(e) to the nearest integer n, whose
#: two's complement then sits in the low bits of the sum
_SHIFT = 6755399441055744.0
_SHIFT_BITS = int(np.array([_SHIFT]).view(np.int64)[0])
#: Taylor coefficients 1/k! of exp(r) on |r| ≤ ln 2 / 2 (truncation < 1e-17)
_C = tuple(1.0 / math.factorial(j) for j in range(14))

if HAVE_NUMBA:
    from ._kernels import _sym3_eig_into  # the closed form shared with the moments

    _C0, _C1, _C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9, _C10, _C11, _C12, _C13 = _C

    @_jit(inline="always")
    def _exp_into(a, m, bits):
        """a[:m] ← exp(a[:m]) in place, within 2 ulp of libm's exp (0 below
        −745.2, as libm).  ``bits`` is int64 scratch of shape (3, ≥ m).

        Every weight of the energy (4.5) and its steps is an exponential (θ, ψ,
        the TV weights, V_n (4.17)), and one libm call costs about as much as
        the rest of a neighbour's term.  Written as three branch-free loops over
        a row's neighbours (reduction and polynomial, the exponent's bits, the
        scaling), LLVM vectorises them, which it cannot do for calls to libm.
        The scale 2ⁿ is applied as two factors so that results below 2⁻¹⁰²²
        round once, to the subnormal libm gives.  Arguments must be finite."""
        f = bits.view(np.float64)
        for j in range(m):
            x = min(max(a[j], -746.0), 709.0)
            t = x * _LOG2E + _SHIFT
            nf = t - _SHIFT
            r = (x - nf * _LN2_HI) - nf * _LN2_LO
            r2 = r * r
            r4 = r2 * r2
            s0 = (_C0 + _C1 * r) + (_C2 + _C3 * r) * r2
            s1 = (_C4 + _C5 * r) + (_C6 + _C7 * r) * r2
            s2 = (_C8 + _C9 * r) + (_C10 + _C11 * r) * r2
            s3 = _C12 + _C13 * r
            f[2, j] = t
            a[j] = (s0 + s1 * r4) + (s2 + s3 * r4) * (r4 * r4)
        for j in range(m):
            n = bits[2, j] - _SHIFT_BITS
            n1 = n >> 1
            bits[0, j] = (n1 + 1023) << 52
            bits[1, j] = (n - n1 + 1023) << 52
        for j in range(m):
            a[j] = a[j] * f[0, j] * f[1, j]

    @_jit()
    def exp_rows(a):
        """exp of a 1-D array by ``_exp_into`` (for the tests)."""
        out = a.copy()
        _exp_into(out, len(out), np.empty((3, len(out)), np.int64))
        return out

    @_jit(inline="always")
    def _up(count):
        """``count`` rounded up to a multiple of 16.  The per-neighbour loops
        run over that many columns, so that their vectorised body (4 lanes ×
        4 interleaved) covers every column and leaves no scalar remainder; the
        columns past the count hold the point itself at distance 0 (finite
        values, never summed), and every sum stops at the count."""
        return (count + 15) // 16 * 16

    @_jit(inline="always")
    def _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits):
        """The neighbours of row i inside the radius, in column order: their
        indices q, D = p_i − p_j, |D|² and θ; ``inside`` flags every column.
        Returns their count.  Every term of the energy (4.5) and of its steps
        carries θ or the radius mask, so the neighbours outside add exactly
        zero and are left out; column 0 (the point itself, at distance 0)
        stays first.  Every column is written at slot m and m advances only
        for those inside (no branch to mispredict); a slot written by one
        outside is overwritten by the next column or by the padding."""
        inv_sd2 = -1.0 / sd2
        m = 0
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        for j in range(idx.shape[1]):
            p = idx[i, j]
            d0 = x0 - x[p, 0]
            d1 = x1 - x[p, 1]
            dz = x2 - x[p, 2]
            s = d0 * d0 + d1 * d1 + dz * dz
            ins = s <= r2
            inside[j] = ins
            q[m] = p
            d[0, m] = d0
            d[1, m] = d1
            d[2, m] = dz
            d2[m] = s
            theta[m] = s * inv_sd2
            m += 1 if ins else 0
        mp = _up(m)
        for j in range(m, mp):  # padding: the point itself, at distance 0
            q[j] = i
            d[0, j] = d[1, j] = d[2, j] = 0.0
            d2[j] = 0.0
            theta[j] = 0.0
        _exp_into(theta, mp, bits)
        return m

    @_jit()
    def _scratch(k):
        """Per-call work arrays of the row kernels: q, d, d2, θ, inside and the
        exponentials' buffer and bits."""
        return (np.empty(k, np.int64), np.empty((3, k)), np.empty(k), np.empty(k),
                np.empty(k, np.bool_), np.empty(k), np.empty((3, k), np.int64))

    @_jit(inline="always")
    def _eta1(res, psi, theta):
        """η = ψθ/|h − τ| of one neighbour (θ where |h − τ| < GUARD)."""
        a = abs(res)
        if a < GUARD:
            return theta
        return psi * theta / a

    @_jit(inline="always")
    def _sum4(v, s, m):
        """Σ v[s:m] as four interleaved partial sums, added (a0 + a1) + (a2 + a3).

        A fixed order, written out, so that every machine gives the same bits
        (numba's fastmath would let LLVM pick the order by the CPU's vector
        width), with four independent additions per step instead of one
        chain, which is what bounds a sum of a few dozen terms."""
        a0 = a1 = a2 = a3 = 0.0
        j = s
        while j + 4 <= m:
            a0 += v[j]
            a1 += v[j + 1]
            a2 += v[j + 2]
            a3 += v[j + 3]
            j += 4
        while j < m:
            a0 += v[j]
            j += 1
        return (a0 + a1) + (a2 + a3)

    @_jit(inline="always")
    def _dot4(u, v, s, m):
        """Σ u[j]·v[j] over s ≤ j < m, in the order of ``_sum4``."""
        a0 = a1 = a2 = a3 = 0.0
        j = s
        while j + 4 <= m:
            a0 += u[j] * v[j]
            a1 += u[j + 1] * v[j + 1]
            a2 += u[j + 2] * v[j + 2]
            a3 += u[j + 3] * v[j + 3]
            j += 4
        while j < m:
            a0 += u[j] * v[j]
            j += 1
        return (a0 + a1) + (a2 + a3)

    @_jit(inline="always")
    def _eta_into(res, psi, theta, m, eta):
        """eta[:m] ← η of every neighbour (``_eta1``), one branch-free loop."""
        for j in range(m):
            eta[j] = _eta1(res[j], psi[j], theta[j])

    @_jit(inline="always")
    def _fid_terms(res, psi, theta, m, out):
        """out[:m] ← |h − τ|·ψ·θ, the fidelity terms of (4.5)."""
        for j in range(m):
            out[j] = abs(res[j]) * psi[j] * theta[j]

    @_jit(inline="always")
    def _tau_irls1(hgt, theta, k, kp, tau, inv_sh2, n_steps, ex, bits, eta):
        """IRLS weighted L1-median of the heights (4.14) from ``tau``; ``ex``,
        ``bits`` and ``eta`` are scratch."""
        for _ in range(n_steps):
            for j in range(kp):
                r = hgt[j] - tau
                ex[j] = r * r * inv_sh2
            _exp_into(ex, kp, bits)
            for j in range(kp):
                eta[j] = _eta1(hgt[j] - tau, ex[j], theta[j])
            den = _sum4(eta, 0, k)
            num = _dot4(eta, hgt, 0, k)
            if den > 0:
                tau = num / den
        return tau

    @_jit()
    def inner_rows(x, idx, normals, tau, s, e, r2, sd2, sh2, lam, cos_n, sn2, l1,
                   propose, want_vn, energy, new_n, new_t, vnorm, offset, curv):
        """Rows s:e of ``_denoise_steps._inner_pass``: the energy of the state
        (normals, τ); with ``propose`` the next state, with ``want_vn`` V_n and
        the height fit (a, c)."""
        k = _up(idx.shape[1])
        q, d, d2, theta, inside, ex, bits = _scratch(k)
        hgt = np.empty(k)
        res = np.empty(k)
        psi = np.empty(k)
        res0 = np.empty(k)
        psi0 = np.empty(k)
        eta = np.empty(k)
        t0 = np.empty(k)
        t1 = np.empty(k)
        al = np.empty((3, k))
        ee = np.empty((3, k))
        w = np.empty(k)
        inv_sh2 = -1.0 / sh2
        inv_cn = 1.0 / (1.0 - cos_n)
        inv_sn = -1.0 / (2.0 * sn2)
        for i in range(s, e):
            m = _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits)
            mp = _up(m)
            n0, n1, n2 = normals[i, 0], normals[i, 1], normals[i, 2]
            t_i = tau[i]
            cnt = m - 1.0  # the point itself adds no TV term
            for j in range(mp):  # exponents of ψ and of the TV weights
                h = d[0, j] * n0 + d[1, j] * n1 + d[2, j] * n2
                hgt[j] = h
                r = h - t_i
                res[j] = r
                psi[j] = r * r * inv_sh2
                c = q[j]
                m0, m1, m2 = normals[c, 0], normals[c, 1], normals[c, 2]
                dot = m0 * n0 + m1 * n1 + m2 * n2
                if dot < 0:
                    m0, m1, m2 = -m0, -m1, -m2
                al[0, j], al[1, j], al[2, j] = m0, m1, m2
                u = (1.0 - abs(dot)) * inv_cn
                w[j] = -(u * u)
            _exp_into(psi, mp, bits)
            _exp_into(w, mp, bits)
            w[0] = 0.0
            _fid_terms(res, psi, theta, mp, t0)
            fid = _sum4(t0, 0, m)
            for j in range(mp):
                e0, e1, e2 = n0 - al[0, j], n1 - al[1, j], n2 - al[2, j]
                if l1:
                    dist = abs(e0) + abs(e1) + abs(e2)
                else:
                    dist = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
                t0[j] = dist * w[j]
            tv = _sum4(t0, 1, m)
            energy[i] = fid + lam * tv
            if not (want_vn or propose):
                continue
            _eta_into(res, psi, theta, mp, eta)
            if want_vn:
                for j in range(mp):
                    e0, e1, e2 = n0 - al[0, j], n1 - al[1, j], n2 - al[2, j]
                    ex[j] = (e0 * e0 + e1 * e1 + e2 * e2) * inv_sn
                _exp_into(ex, mp, bits)
                acc = _sum4(ex, 1, m)
                for j in range(mp):
                    rho2 = max(d2[j] - hgt[j] * hgt[j], 0.0)
                    t0[j] = rho2
                    t1[j] = eta[j] * rho2
                s0 = _sum4(eta, 0, m)
                s1 = _sum4(t1, 0, m)
                s2 = _dot4(t1, t0, 0, m)
                b0 = _dot4(eta, hgt, 0, m)
                b1 = _dot4(t1, hgt, 0, m)
                vnorm[i] = acc / cnt if cnt > 0 else 1.0
                det = s0 * s2 - s1 * s1
                if det > 1e-9 * max(s0 * s2, 1e-300):
                    offset[i] = (b0 * s2 - b1 * s1) / det
                    curv[i] = (s0 * b1 - s1 * b0) / det
                else:
                    offset[i] = t_i
                    curv[i] = 0.0
            if not propose:
                continue
            # τ step (4.14), kept only if it does not raise the fidelity term
            den = _sum4(eta, 0, m)
            num = _dot4(eta, hgt, 0, m)
            t_new = num / den if den > 0 else t_i
            if t_new != t_i:
                for j in range(mp):
                    res0[j] = res[j]
                    psi0[j] = psi[j]
                    r = hgt[j] - t_new
                    res[j] = r  # the state at the new τ, for the normal step
                    psi[j] = r * r * inv_sh2
                _exp_into(psi, mp, bits)
                _fid_terms(res, psi, theta, mp, t0)
                f_new = _sum4(t0, 0, m)
                if f_new > fid:  # back to τ_i
                    t_new = t_i
                    for j in range(mp):
                        res[j] = res0[j]
                        psi[j] = psi0[j]
                else:
                    _eta_into(res, psi, theta, mp, eta)
            new_t[i] = t_new
            # normal step (4.10)-(4.12) at the new τ
            lip = _dot4(eta, d2, 0, m)
            for j in range(mp):
                t1[j] = eta[j] * res[j]
            g0 = _dot4(t1, d[0], 0, m)
            g1 = _dot4(t1, d[1], 0, m)
            g2 = _dot4(t1, d[2], 0, m)
            gamma = 1.0 / lip if lip > 0 else 0.0
            h0, h1, h2 = n0 - gamma * g0, n1 - gamma * g1, n2 - gamma * g2
            scale = gamma * lam * cnt
            for j in range(mp):
                thr = w[j] * scale
                e0, e1, e2 = h0 - al[0, j], h1 - al[1, j], h2 - al[2, j]
                if l1:  # (4.12) per component: clip(d, ±t)
                    e0 = min(max(e0, -thr), thr)
                    e1 = min(max(e1, -thr), thr)
                    e2 = min(max(e2, -thr), thr)
                else:   # vector soft threshold: d·min(1, t/‖d‖)
                    ln = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
                    fac = min(thr / max(ln, 1e-30), 1.0)
                    e0, e1, e2 = e0 * fac, e1 * fac, e2 * fac
                ee[0, j], ee[1, j], ee[2, j] = e0, e1, e2
            a0 = _sum4(ee[0], 1, m)
            a1 = _sum4(ee[1], 1, m)
            a2 = _sum4(ee[2], 1, m)
            c = max(cnt, 1.0)
            v0, v1, v2 = h0 - a0 / c, h1 - a1 / c, h2 - a2 / c
            nv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            if nv > 1e-12:
                new_n[i, 0], new_n[i, 1], new_n[i, 2] = v0 / nv, v1 / nv, v2 / nv
            else:
                new_n[i, 0], new_n[i, 1], new_n[i, 2] = n0, n1, n2

    @_jit()
    def move_sq(x, t_new, n_new, t_old, n_old, out):
        """out[i] ← |(p − τ'n') − (p − τn)|², summed over the coordinates in
        order, as NumPy's row sum does."""
        for i in range(len(x)):
            acc = 0.0
            for c in range(3):
                a = ((x[i, c] - t_new[i] * n_new[i, c])
                     - (x[i, c] - t_old[i] * n_old[i, c]))
                if c == 0:
                    acc = a * a
                else:
                    acc += a * a
            out[i] = acc

    @_jit()
    def eigen_rows(x, idx, normals, tau, s, e, r2, sd2, sh2, first, out_n, out_t):
        """Rows s:e of one pass of (4.9) (``_denoise_steps._eigen_pass``)."""
        k = _up(idx.shape[1])
        q, d, d2, theta, inside, ex, bits = _scratch(k)
        hgt = np.empty(k)
        om = np.empty(k)
        lam = np.empty((1, 1, 3))
        vec = np.empty((1, 1, 3))
        inv_sh2 = -1.0 / sh2
        for i in range(s, e):
            m = _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits)
            mp = _up(m)
            if first:  # θ-weighted PCA about the weighted mean
                ws = _sum4(theta, 0, m)
                for j in range(mp):
                    om[j] = theta[j] / ws
                m0 = _dot4(om, d[0], 0, m)
                m1 = _dot4(om, d[1], 0, m)
                m2 = _dot4(om, d[2], 0, m)
                t = 0.0
            else:  # about c_i = p_i − τ_i n_i, ω = ψθ/|h − τ|
                n0, n1, n2 = normals[i, 0], normals[i, 1], normals[i, 2]
                for j in range(mp):
                    hgt[j] = d[0, j] * n0 + d[1, j] * n1 + d[2, j] * n2
                t = _tau_irls1(hgt, theta, m, mp, tau[i], inv_sh2, TAU_IRLS, ex, bits, om)
                for j in range(mp):
                    r = hgt[j] - t
                    ex[j] = r * r * inv_sh2
                _exp_into(ex, mp, bits)
                for j in range(mp):
                    om[j] = _eta1(hgt[j] - t, ex[j], theta[j])
                m0, m1, m2 = t * n0, t * n1, t * n2
            c00 = c01 = c02 = c11 = c12 = c22 = 0.0
            for j in range(m):
                q0, q1, q2 = d[0, j] - m0, d[1, j] - m1, d[2, j] - m2
                o = om[j]
                c00 += o * q0 * q0
                c01 += o * q0 * q1
                c02 += o * q0 * q2
                c11 += o * q1 * q1
                c12 += o * q1 * q2
                c22 += o * q2 * q2
            _sym3_eig_into(c00, c01, c02, c11, c12, c22, lam, vec, 0, 0)
            out_n[i, 0], out_n[i, 1], out_n[i, 2] = vec[0, 0, 0], vec[0, 0, 1], vec[0, 0, 2]
            out_t[i] = t

    @_jit()
    def select_rows(x, idx, normals, cols, s, e, r2, sd2, sh2, out_n, out_t):
        """Rows s:e of ``_denoise_steps._select_candidates``: of the own normal
        and those of the neighbours ``cols`` (inside the radius), the one of
        lowest Welsch loss Σ θ(1 − ψ), with τ by (4.14) from 0."""
        k = _up(idx.shape[1])
        q, d, d2, theta, inside, ex, bits = _scratch(k)
        hgt = np.empty(k)
        eta = np.empty(k)
        inv_sh2 = -1.0 / sh2
        for i in range(s, e):
            m = _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits)
            mp = _up(m)
            best = np.inf
            bq = i
            bt = 0.0
            for c in range(len(cols) + 1):
                if c == 0:
                    p = i
                elif inside[cols[c - 1]]:
                    p = idx[i, cols[c - 1]]
                else:
                    continue
                n0, n1, n2 = normals[p, 0], normals[p, 1], normals[p, 2]
                for j in range(mp):
                    hgt[j] = d[0, j] * n0 + d[1, j] * n1 + d[2, j] * n2
                t = _tau_irls1(hgt, theta, m, mp, 0.0, inv_sh2, TAU_IRLS, ex, bits, eta)
                for j in range(mp):
                    r = hgt[j] - t
                    ex[j] = r * r * inv_sh2
                _exp_into(ex, mp, bits)
                for j in range(mp):
                    eta[j] = (1.0 - ex[j]) * theta[j]
                loss = _sum4(eta, 0, m)
                if loss < best:
                    best, bq, bt = loss, p, t
            out_n[i, 0], out_n[i, 1], out_n[i, 2] = (normals[bq, 0], normals[bq, 1],
                                                     normals[bq, 2])
            out_t[i] = bt

    @_jit()
    def curvature_rows(x, idx, normals, curv, s, e, r2, sd2, out):
        """Rows s:e of ``_denoise_steps._smooth_curvature``: the θ-weighted mean
        of the neighbours' curvatures, each signed to agree with n_i."""
        q, d, d2, theta, inside, ex, bits = _scratch(_up(idx.shape[1]))
        for i in range(s, e):
            m = _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits)
            mp = _up(m)
            for j in range(mp):
                c = q[j]
                dot = (normals[i, 0] * normals[c, 0] + normals[i, 1] * normals[c, 1]
                       + normals[i, 2] * normals[c, 2])
                ex[j] = theta[j] * (-curv[c] if dot < 0 else curv[c])
            num = _sum4(ex, 0, m)
            den = _sum4(theta, 0, m)
            out[i] = num / max(den, 1e-300)

    @_jit()
    def sphere_rows(x, idx, fit_n, xs, s, e, r2, sd2, cos_n, gap, n_steps, off, ok):
        """Rows s:e of ``_denoise_project._sphere_project``: the weighted
        algebraic sphere fit about p_i (neighbours on another sheet of the
        filtered positions ``xs`` left out) and the Newton steps onto it."""
        q, d, d2, theta, inside, ex, bits = _scratch(_up(idx.shape[1]))
        inv_cn = 1.0 / (1.0 - cos_n)
        for i in range(s, e):
            m = _neigh(x, idx, i, r2, sd2, q, d, d2, theta, inside, bits)
            mp = _up(m)
            r0, r1, r2_ = fit_n[i, 0], fit_n[i, 1], fit_n[i, 2]
            for j in range(mp):
                c = q[j]
                dot = fit_n[c, 0] * r0 + fit_n[c, 1] * r1 + fit_n[c, 2] * r2_
                u = (1.0 - abs(dot)) * inv_cn
                ex[j] = -(u * u)
            _exp_into(ex, mp, bits)
            for j in range(m):  # another sheet: a height the normals' turn does not explain
                c = q[j]
                dot = fit_n[c, 0] * r0 + fit_n[c, 1] * r1 + fit_n[c, 2] * r2_
                hs = ((xs[c, 0] - xs[i, 0]) * r0 + (xs[c, 1] - xs[i, 1]) * r1
                      + (xs[c, 2] - xs[i, 2]) * r2_)
                turn = 0.5 * np.sqrt(d2[j]) * np.sqrt(max(1.0 - dot * dot, 0.0))
                if abs(hs) > turn + gap:
                    ex[j] = 0.0
            s0 = qq = qn = 0.0
            mq0 = mq1 = mq2 = mn0 = mn1 = mn2 = 0.0
            for j in range(m):
                c = q[j]
                b0, b1, b2 = fit_n[c, 0], fit_n[c, 1], fit_n[c, 2]
                if b0 * r0 + b1 * r1 + b2 * r2_ < 0:
                    b0, b1, b2 = -b0, -b1, -b2
                w = ex[j] * theta[j]
                p0, p1, p2 = -d[0, j], -d[1, j], -d[2, j]  # p_j − p_i
                s0 += w
                mq0 += w * p0
                mq1 += w * p1
                mq2 += w * p2
                mn0 += w * b0
                mn1 += w * b1
                mn2 += w * b2
                qq += w * d2[j]
                qn += w * (p0 * b0 + p1 * b1 + p2 * b2)
            good = s0 > 0
            inv = 1.0 / s0 if good else 1.0
            mq0, mq1, mq2 = mq0 * inv, mq1 * inv, mq2 * inv
            mn0, mn1, mn2 = mn0 * inv, mn1 * inv, mn2 * inv
            qq *= inv
            qn *= inv
            den = qq - (mq0 * mq0 + mq1 * mq1 + mq2 * mq2)
            if den <= 1e-9 * max(qq, 1e-300):
                u4 = 0.0
            else:
                u4 = 0.5 * (qn - (mq0 * mn0 + mq1 * mn1 + mq2 * mn2)) / den
            u0_, u1_, u2_ = mn0 - 2.0 * u4 * mq0, mn1 - 2.0 * u4 * mq1, mn2 - 2.0 * u4 * mq2
            c0 = -(u0_ * mq0 + u1_ * mq1 + u2_ * mq2) - u4 * qq
            x0 = x1 = x2 = 0.0
            for _ in range(n_steps):  # Newton along ∇s
                g0, g1, g2 = u0_ + 2.0 * u4 * x0, u1_ + 2.0 * u4 * x1, u2_ + 2.0 * u4 * x2
                f = c0 + (u0_ * x0 + u1_ * x1 + u2_ * x2) + u4 * (x0 * x0 + x1 * x1 + x2 * x2)
                gg = g0 * g0 + g1 * g1 + g2 * g2
                st = f / gg if gg > 1e-24 else 0.0
                x0, x1, x2 = x0 - st * g0, x1 - st * g1, x2 - st * g2
            good = good and np.isfinite(x0) and np.isfinite(x1) and np.isfinite(x2)
            ok[i] = good
            if good:
                off[i, 0], off[i, 1], off[i, 2] = x0, x1, x2
            else:
                off[i, 0], off[i, 1], off[i, 2] = 0.0, 0.0, 0.0
