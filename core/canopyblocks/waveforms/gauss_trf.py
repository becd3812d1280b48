"""scipy's bounded trust-region reflective least squares, run on many shots at once.

The decomposition fits shots with several Gaussians with
``scipy.optimize.least_squares(method="trf", x_scale="jac")`` and an analytic Jacobian:
such fits have several local minima and the path decides which one is reached, so a
different solver gives different fits. This module takes the same steps as scipy's
``trf_bounds`` (exact trust-region subproblem by one SVD per iteration, Coleman-Li
scaling, reflective step selection, the same radius update and stopping tests) for a
batch of shots with the same number of parameters, each shot at its own iteration:
every numpy call works on all shots still running. Padding samples carry weight 0
(zero rows of the Jacobian, which change neither its singular values nor ``U^T f``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .gauss_lm import _model_and_jacobian

__all__ = ["trf_many"]

FloatArray = npt.NDArray[np.float64]
EPS = np.finfo(float).eps


def _norm(a: FloatArray) -> FloatArray:
    return np.sqrt(np.einsum("...i,...i->...", a, a))


def _strictly_feasible(x: FloatArray, lb: FloatArray, ub: FloatArray, rstep: float
                       ) -> FloatArray:
    """scipy's ``make_strictly_feasible`` on every row."""
    out = x.copy()
    if rstep == 0:
        upper = x >= ub
        lower = (x <= lb) & ~upper
    else:
        ld, ud = x - lb, ub - x
        upper = ud <= np.minimum(ld, rstep * np.maximum(1, np.abs(ub)))
        lower = (ld <= np.minimum(ud, rstep * np.maximum(1, np.abs(lb)))) & ~upper
    if rstep == 0:
        out = np.where(lower, np.nextafter(lb, ub), out)
        out = np.where(upper, np.nextafter(ub, lb), out)
    else:
        out = np.where(lower, lb + rstep * np.maximum(1, np.abs(lb)), out)
        out = np.where(upper, ub - rstep * np.maximum(1, np.abs(ub)), out)
    tight = (out < lb) | (out > ub)
    return np.where(tight, 0.5 * (lb + ub), out)


def _step_to_bound(x: FloatArray, s: FloatArray, lb: FloatArray, ub: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:
    """scipy's ``step_size_to_bound`` per row: (min step, hits)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        steps = np.where(s != 0, np.maximum((lb - x) / s, (ub - x) / s), np.inf)
    m = steps.min(axis=1)
    hits = (steps == m[:, None]) * np.sign(s).astype(int)
    return m, hits


def _quadratic(r: FloatArray, gh: FloatArray, s: FloatArray) -> FloatArray:
    """scipy's ``evaluate_quadratic`` per row, ``0.5 s (J_h^T J_h + diag_h) s + g_h s``,
    from the R factor of ``[J_h; diag_h^1/2]`` (``R^T R = J_h^T J_h + diag_h``)."""
    rs = np.einsum("bij,bj->bi", r, s)
    return 0.5 * np.einsum("bi,bi->b", rs, rs) + np.einsum("bi,bi->b", s, gh)


def _min_quad_1d(a: FloatArray, b: FloatArray, lo: FloatArray, hi: FloatArray, c: FloatArray
                 ) -> tuple[FloatArray, FloatArray]:
    """scipy's ``minimize_quadratic_1d`` per row (candidates lo, hi, the extremum)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ext = -0.5 * b / a
    has_ext = (a != 0) & (lo < ext) & (ext < hi)
    t = np.stack([lo, hi, np.where(has_ext, ext, lo)], axis=1)
    y = t * (a[:, None] * t + b[:, None]) + c[:, None]
    y[:, 2] = np.where(has_ext, y[:, 2], np.inf)
    k = np.argmin(y, axis=1)
    r = np.arange(len(a))
    return t[r, k], y[r, k]


def _solve_tr(m: FloatArray, uf: FloatArray, s: FloatArray, V: FloatArray, Delta: FloatArray,
              alpha0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """scipy's ``solve_lsq_trust_region`` per row: (p, alpha)."""
    n = s.shape[1]
    suf = s * uf
    full = (m >= n) & (s[:, -1] > EPS * m * s[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        p_gn = -np.einsum("bij,bj->bi", V, np.where(full[:, None], uf / s, 0.0))
    gn = full & (_norm(p_gn) <= Delta)

    def phi_d(alpha: FloatArray) -> tuple[FloatArray, FloatArray]:
        denom = s ** 2 + alpha[:, None]
        p_norm = _norm(suf / denom)
        return p_norm - Delta, -np.sum(suf ** 2 / denom ** 3, axis=1) / p_norm

    with np.errstate(divide="ignore", invalid="ignore"):
        upper = _norm(suf) / Delta
        ph0, dph0 = phi_d(np.zeros(len(Delta)))
        lower = np.where(full, -ph0 / dph0, 0.0)
        start = np.maximum(0.001 * upper, np.sqrt(lower * upper))
        alpha = np.where(~full & (alpha0 == 0), start, alpha0)
        run = ~gn
        for _ in range(10):
            if not run.any():
                break
            out = (alpha < lower) | (alpha > upper)
            alpha = np.where(run & out, np.maximum(0.001 * upper, np.sqrt(lower * upper)),
                             alpha)
            phi, dphi = phi_d(alpha)
            upper = np.where(run & (phi < 0), alpha, upper)
            ratio = phi / dphi
            lower = np.where(run, np.maximum(lower, alpha - ratio), lower)
            alpha = np.where(run, alpha - (phi + Delta) * ratio / Delta, alpha)
            run &= ~(np.abs(phi) < 0.01 * Delta)
        p = -np.einsum("bij,bj->bi", V, suf / (s ** 2 + alpha[:, None]))
        p *= (Delta / _norm(p))[:, None]
    p = np.where(gn[:, None], p_gn, p)
    return p, np.where(gn, 0.0, alpha)


def _select_step(x: FloatArray, rf: FloatArray, gh: FloatArray,
                 p: FloatArray, ph: FloatArray, d: FloatArray, Delta: FloatArray,
                 lb: FloatArray, ub: FloatArray, theta: FloatArray
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """scipy's ``select_step`` per row: (step, step_h, predicted reduction); its
    quadratic forms in ``J_h`` and ``diag_h`` taken with the R factor ``rf``."""
    inside = ((x + p >= lb) & (x + p <= ub)).all(axis=1)
    step, step_h = p.copy(), ph.copy()
    pred = -_quadratic(rf, gh, ph)
    out = np.nonzero(~inside)[0]
    if not len(out):
        return step, step_h, pred
    x, rf, gh = x[out], rf[out], gh[out]
    p, ph, d, Delta, lb, ub, theta = p[out], ph[out], d[out], Delta[out], lb[out], ub[out], \
        theta[out]
    p_stride, hits = _step_to_bound(x, p, lb, ub)
    r_h = np.where(hits != 0, -ph, ph)
    r = d * r_h
    p = p * p_stride[:, None]
    ph = ph * p_stride[:, None]
    x_on = x + p
    # intersect_trust_region(ph, r_h, Delta): the larger root
    a_ = np.einsum("bi,bi->b", r_h, r_h)
    b_ = np.einsum("bi,bi->b", ph, r_h)
    c_ = np.einsum("bi,bi->b", ph, ph) - Delta ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        dd = np.sqrt(b_ * b_ - a_ * c_)
        q = -(b_ + np.copysign(dd, b_))
        to_tr = np.maximum(q / a_, c_ / q)
    to_bound, _ = _step_to_bound(x_on, r, lb, ub)
    r_stride = np.minimum(to_bound, to_tr)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_lo = np.where(r_stride > 0, (1 - theta) * p_stride / r_stride, 0.0)
    r_hi = np.where(r_stride > 0, np.where(r_stride == to_bound, theta * to_bound, to_tr), -1.0)
    can = r_lo <= r_hi
    # build_quadratic_1d(J_h, g_h, r_h, s0=p_h, diag)
    v = np.einsum("bij,bj->bi", rf, r_h)
    a1 = 0.5 * np.einsum("bi,bi->b", v, v)
    u = np.einsum("bij,bj->bi", rf, ph)
    b1 = np.einsum("bi,bi->b", gh, r_h) + np.einsum("bi,bi->b", u, v)
    c1 = 0.5 * np.einsum("bi,bi->b", u, u) + np.einsum("bi,bi->b", gh, ph)
    rs, r_value = _min_quad_1d(a1, b1, r_lo, r_hi, c1)
    r_h = r_h * rs[:, None] + ph
    r = r_h * d
    r_value = np.where(can, r_value, np.inf)
    p = p * theta[:, None]
    ph = ph * theta[:, None]
    p_value = _quadratic(rf, gh, ph)
    ag_h = -gh
    ag = d * ag_h
    to_tr2 = Delta / _norm(ag_h)
    to_b2, _ = _step_to_bound(x, ag, lb, ub)
    ag_stride = np.where(to_b2 < to_tr2, theta * to_b2, to_tr2)
    va = np.einsum("bij,bj->bi", rf, ag_h)
    a2 = 0.5 * np.einsum("bi,bi->b", va, va)
    b2 = np.einsum("bi,bi->b", gh, ag_h)
    ag_stride, ag_value = _min_quad_1d(a2, b2, np.zeros(len(a2)), ag_stride, np.zeros(len(a2)))
    ag_h = ag_h * ag_stride[:, None]
    ag = ag * ag_stride[:, None]
    use_p = (p_value < r_value) & (p_value < ag_value)
    use_r = ~use_p & (r_value < ag_value)
    sel = np.where(use_p[:, None], p, np.where(use_r[:, None], r, ag))
    sel_h = np.where(use_p[:, None], ph, np.where(use_r[:, None], r_h, ag_h))
    val = np.where(use_p, p_value, np.where(use_r, r_value, ag_value))
    step[out], step_h[out], pred[out] = sel, sel_h, -val
    return step, step_h, pred


def trf_many(x: FloatArray, y: FloatArray, weight: FloatArray, p0: FloatArray,
             lower: FloatArray, upper: FloatArray, max_nfev: int) -> FloatArray:
    """Parameters (B, n) that ``least_squares(method="trf", x_scale="jac")`` reaches
    from ``p0`` for each row (positions ``x``, samples ``y``, weight 1 on the shot's
    window and 0 on padding; ``lower`` / ``upper`` bounds)."""
    ftol = xtol = gtol = 1e-8
    lb, ub = lower, upper
    m = weight.sum(axis=1)
    yw = y * weight
    xk = _strictly_feasible(p0, lb, ub, 1e-10)

    def evaluate(rows: npt.NDArray[np.intp], params: FloatArray) -> tuple[FloatArray, FloatArray]:
        model, jac = _model_and_jacobian(x[rows], params, weight[rows])
        return model - yw[rows], jac

    all_rows = np.arange(len(xk))
    f, J = evaluate(all_rows, xk)
    cost = 0.5 * np.einsum("bi,bi->b", f, f)
    g = np.einsum("bij,bi->bj", J, f)
    scale_inv = np.sqrt(np.einsum("bij,bij->bj", J, J))
    scale_inv[scale_inv == 0] = 1
    scale = 1 / scale_inv
    v = np.ones_like(xk)
    v = np.where(g < 0, ub - xk, np.where(g > 0, xk - lb, v))
    dv = np.where(g < 0, -1.0, np.where(g > 0, 1.0, 0.0))
    v = np.where(dv != 0, v * scale_inv, v)
    Delta = _norm(xk * scale_inv / v ** 0.5)
    Delta[Delta == 0] = 1.0
    alpha = np.zeros(len(xk))
    nfev = np.ones(len(xk), dtype=np.int64)
    running = np.ones(len(xk), dtype=bool)
    n_par = xk.shape[1]
    width = x.shape[1]
    d = np.zeros_like(xk)
    g_h = np.zeros_like(xk)
    uf = np.zeros_like(xk)
    sv = np.zeros_like(xk)
    V = np.zeros((len(xk), n_par, n_par))
    R = np.zeros((len(xk), n_par, n_par))
    theta = np.zeros(len(xk))
    idx = np.arange(n_par)

    def refresh(new: npt.NDArray[np.intp], jac: FloatArray) -> None:
        """The start of scipy's outer iteration for the rows ``new`` (Jacobian ``jac``),
        at a new point: the stopping test on the gradient, the scaling, and the SVD of
        the augmented Jacobian [J_h; diag_h^1/2] by way of its R factor: R = U_r S V^T,
        U^T f = U_r^T Q^T f, and Q^T f is the last column of the R factor of [J_h f]
        (LAPACK's SVD of a tall matrix starts with the same QR). R also gives the
        quadratic forms of the step selection (R^T R = J_h^T J_h + diag_h)."""
        xr, gr = xk[new], g[new]
        v = np.where(gr < 0, ub[new] - xr, np.where(gr > 0, xr - lb[new], 1.0))
        dv = np.where(gr < 0, -1.0, np.where(gr > 0, 1.0, 0.0))
        g_norm = np.abs(gr * v).max(axis=1)
        stop = (g_norm < gtol) | (nfev[new] >= max_nfev)
        running[new[stop]] = False
        keep = ~stop
        new, v, dv, gr, g_norm = new[keep], v[keep], dv[keep], gr[keep], g_norm[keep]
        if not len(new):
            return
        v = np.where(dv != 0, v * scale_inv[new], v)
        dn = v ** 0.5 * scale[new]
        d[new] = dn
        g_h[new] = dn * gr
        aug = np.zeros((len(new), width + n_par, n_par + 1))
        aug[:, :width, :n_par] = jac[keep] * dn[:, None, :]
        aug[:, width + idx, idx] = (gr * dv * scale[new]) ** 0.5
        aug[:, :width, n_par] = f[new]
        r_ext: FloatArray = np.asarray(np.linalg.qr(aug, mode="r"))
        R[new] = r_ext[:, :n_par, :n_par]
        U, s_, Vt = np.linalg.svd(R[new])
        sv[new] = s_
        V[new] = np.swapaxes(Vt, 1, 2)
        uf[new] = np.einsum("bki,bk->bi", U, r_ext[:, :n_par, n_par])
        theta[new] = np.maximum(0.995, 1 - g_norm)

    refresh(all_rows, J)
    del J
    for _ in range(100 * max_nfev):
        act = np.nonzero(running)[0]
        if not len(act):
            break
        p_h, alpha_new = _solve_tr(m[act], uf[act], sv[act], V[act], Delta[act], alpha[act])
        alpha[act] = alpha_new
        p = d[act] * p_h
        step, step_h, pred = _select_step(xk[act], R[act], g_h[act], p, p_h,
                                          d[act], Delta[act], lb[act], ub[act], theta[act])
        x_new = _strictly_feasible(xk[act] + step, lb[act], ub[act], 0.0)
        f_new, J_new = evaluate(act, x_new)
        nfev[act] += 1
        step_h_norm = _norm(step_h)
        finite = np.isfinite(f_new).all(axis=1)
        cost_new = 0.5 * np.einsum("bi,bi->b", f_new, f_new)
        red = cost[act] - cost_new
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(pred > 0, red / pred, np.where((pred == 0) & (red == 0), 1.0, 0.0))
        D_old = Delta[act]
        D_new = np.where(ratio < 0.25, 0.25 * step_h_norm,
                         np.where((ratio > 0.75) & (step_h_norm > 0.95 * D_old), 2.0 * D_old,
                                  D_old))
        step_norm = _norm(step)
        ftol_ok = (red < ftol * cost[act]) & (ratio > 0.25)
        xtol_ok = step_norm < xtol * (xtol + _norm(xk[act]))
        done = (ftol_ok | xtol_ok) & finite
        upd = ~done & finite
        with np.errstate(divide="ignore", invalid="ignore"):
            alpha[act] = np.where(upd, alpha[act] * D_old / D_new, alpha[act])
        Delta[act] = np.where(upd, D_new, np.where(finite, D_old, 0.25 * step_h_norm))
        accept = finite & (red > 0)
        acc = act[accept]
        J_acc = J_new[accept]
        xk[acc] = x_new[accept]
        f[acc] = f_new[accept]
        cost[acc] = cost_new[accept]
        g[acc] = np.einsum("bij,bi->bj", J_acc, f_new[accept])
        si = np.sqrt(np.einsum("bij,bij->bj", J_acc, J_acc))
        scale_inv[acc] = np.maximum(si, scale_inv[acc])
        scale[acc] = 1 / scale_inv[acc]
        running[act[done]] = False
        # the inner loop also ends at max_nfev without a reduction
        running[act[~accept & (nfev[act] >= max_nfev)]] = False
        go_on = running[acc]
        refresh(acc[go_on], J_acc[go_on])
    return xk
