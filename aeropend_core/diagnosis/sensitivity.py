"""Exact sensitivities of the output-error simulation: the derivative of the simulated angle with respect to the
parameters and the segments' initial states, integrated alongside the state by the same RK4 steps.

The output-error fit (:mod:`aeropend_core.diagnosis.output_error`) needs the Jacobian of its residuals. Forward
differences cost n_free + 2 simulations per Jacobian; here one pass carries, with the state (angle y, rate W,
lagged thrust f), its derivative S = d(y, W, f) / d(column) for each tracked column of the kernel's parameter row
and for the segment's initial angle and rate. Every RK4 stage is differentiated as it is computed (the forward
mode of the discrete scheme), so the result is the exact derivative of the discrete simulation, not of the ODE:
the Jacobian of the residuals the optimiser sees, to rounding.

Covered (the built-in smooth terms): gravity_stiffness, damping, thrust_gain and armature_resistance (row columns
0-3), dry friction with its smoothed sign (4; with the widening of its smoothing above the RK4 limit), quadratic
drag (5), the linear angle term (6), the angle offset (7) and the thrust lag's time constant (8). Not covered
(the caller keeps forward differences for them): the thrust gate's threshold (9: the gate is a step in Va, its
derivative is zero or a Dirac), discovered terms and users' effects (their derivatives are not known here) and a
sensor low-pass after the simulation. The lag filter's pre-roll length, int(5 tau / Ts) samples, is a step in
tau and is held fixed in the derivative, as forward differences of 1e-6 relative see it.
"""
from __future__ import annotations

import math

import numba
import numpy as np

#: Row columns whose derivative :func:`sensitivity_kernel` computes (gravity .. thrust lag time constant).
EXACT_COLUMNS = frozenset(range(9))
#: Row column of the angle offset (its derivative is 1 on every simulated sample).
OFFSET_COLUMN = 7
#: Row column of the thrust lag's time constant.
LAG_COLUMN = 8

_F1, _F2, _I1 = numba.float64[::1], numba.float64[:, ::1], numba.int64[::1]


@numba.njit(cache=True, nogil=True, inline='always')
def _without_friction(fc):
    """Whether the dry-friction coefficient is +0 (not -0: its zero has the other sign), so its tanh can be skipped."""
    return fc == 0.0 and math.copysign(1.0, fc) > 0.0


@numba.njit(cache=True, nogil=True, inline='always')
def friction_term(fc, w, smooth):
    """Dry friction's acceleration fc tanh(w / smooth) [rad/s^2]; +0.0 without friction (fc = +0), its tanh skipped.

    Exact in the rates it is subtracted from: +0 tanh(.) is a zero of the sign of w, and x - (-0) differs from
    x - 0 only for x = -0, which the rate sum -a sin y - b w + t never is when w <= -0 (-b w is then positive or
    +0, and a sum with a nonzero or +0 term is not -0), as in the simulator (sim/simulate._rig_rates). A -0
    coefficient keeps the product (its zero has the other sign)."""
    return 0.0 if _without_friction(fc) else fc * math.tanh(w / smooth)


@numba.njit(cache=True, nogil=True, inline='always')
def _thrust_derivative(col, k, e, current, gate):
    """d (k e|e| gate) / d theta[col] with e = Va - R Ia: thrust gain (2) and armature resistance (3); else 0."""
    if col == 2:
        return e * abs(e) * gate
    if col == 3:
        return -2.0 * k * abs(e) * current * gate
    return 0.0


@numba.njit(cache=True, nogil=True, inline='always')
def _stage(y, w, f, u, du, sy, sw, sf, cols, m, a, b, fc, cd, kc, tau, tau_free, smooth, stiff_friction, lag_on,
           ky, kw, kf, need_tanh):
    """One RK4 stage's derivative of (y, W, f) and of their sensitivities (written into ky, kw, kf).

    `u` is the stage's thrust input [rad/s^2] and `du` its derivative per tracked column; returns (dy, dW, df).
    Without `need_tanh` (no friction, its coefficient not tracked) the tanh is skipped as in :func:`friction_term`:
    fc tanh and fc sech^2 are zeros of the same signs either way."""
    t = f if lag_on else u
    q = w / smooth
    th = math.tanh(q) if need_tanh else 0.0
    sech2 = 1.0 - th * th
    dw = -a * math.sin(y) - b * w + t - fc * th - cd * w * abs(w) - kc * y
    df = (u - f) / tau
    fy = -a * math.cos(y) - kc
    fw = -b - fc * sech2 / smooth - 2.0 * cd * abs(w)
    for c in range(m):
        st = sf[c] if lag_on else du[c]
        value = fy * sy[c] + fw * sw[c] + st
        col = cols[c]
        if col == 0:
            value -= math.sin(y)
        elif col == 1:
            value -= w
        elif col == 4:
            value -= th
            if stiff_friction:          # smooth = fc h / stability: the width moves with fc
                value += sech2 * q
        elif col == 5:
            value -= w * abs(w)
        elif col == 6:
            value -= y
        ky[c] = sw[c]
        kw[c] = value
        if lag_on:
            g = (du[c] - sf[c]) / tau
            if col == LAG_COLUMN and tau_free:
                g -= (u - f) / (tau * tau)
            kf[c] = g
        else:
            kf[c] = 0.0
    return w, dw, df


@numba.njit(cache=True, nogil=True, inline='always')
def _stage_point(sy, sw, sf, ky, kw, kf, step, m, ty, tw, tf):
    """The sensitivities at an RK4 stage point: (ty, tw, tf) = (sy, sw, sf) + step * (ky, kw, kf), first m."""
    for c in range(m):
        ty[c] = sy[c] + step * ky[c]
        tw[c] = sw[c] + step * kw[c]
        tf[c] = sf[c] + step * kf[c]


@numba.njit(numba.void(_F1, _F1, _F1, _F1, _I1, _I1, _F2, numba.float64, numba.boolean, numba.boolean,
                       numba.float64, numba.float64, numba.float64, numba.float64, _I1, _F2, _F2, _F2),
            cache=True, nogil=True)
def sensitivity_kernel(theta, voltage, current, gate_signal, seg_start, seg_stop, initial, sample_time, lag_on,
                       gate_on, friction_smoothing, min_time_constant, friction_stability, stride_f, cols, out,
                       d_columns, d_initial):
    """RK4 free-run of one parameter row with its forward sensitivities.

    Parameters
    ----------
    theta : ndarray (width,) [SI per column]
        The parameter row (columns as in the output-error kernel).
    voltage, current, gate_signal : ndarray (n,) [V, A, V]
    seg_start, seg_stop : ndarray of int (segments,) [samples]
    initial : ndarray (segments, 2) [rad, rad/s]
    sample_time : float [s]
    lag_on, gate_on : bool
    friction_smoothing, min_time_constant, friction_stability, stride_f : float [rad/s, s, -, samples]
        The kernel's constants (stride as a float).
    cols : ndarray of int (m,) [-]
        Row columns to differentiate (each in :data:`EXACT_COLUMNS`).
    out : ndarray (1, n) [rad]
        Predicted measured angle, written on the simulated samples (as the output-error kernel writes it).
    d_columns : ndarray (n, m) [rad per column unit]
        d out / d theta[cols[c]] on the simulated samples.
    d_initial : ndarray (n, 2) [rad/rad, rad/(rad/s)]
        d out / d (initial angle, initial rate) of the sample's own segment.
    """
    stride = int(stride_f)
    h = stride * sample_time
    a = theta[0]
    b = theta[1]
    k = theta[2]
    r = theta[3]
    fc = theta[4]
    cd = theta[5]
    kc = theta[6]
    offset = theta[7]
    tau_free = theta[8] >= min_time_constant
    tau = max(theta[8], min_time_constant)
    vth = theta[9]
    stiff_friction = fc * h / friction_stability > friction_smoothing
    smooth = fc * h / friction_stability if stiff_friction else friction_smoothing
    m_cols = cols.shape[0]
    m = m_cols + 2                       # the tracked columns, then the initial angle and rate
    need_tanh = not _without_friction(fc)      # as friction_term: a +0 coefficient skips it
    track = np.empty(m, dtype=np.int64)
    for c in range(m_cols):
        track[c] = cols[c]
        if cols[c] == 4:
            need_tanh = True
    track[m_cols] = -1
    track[m_cols + 1] = -2
    sy = np.zeros(m)
    sw = np.zeros(m)
    sf = np.zeros(m)
    du0 = np.zeros(m)
    du1 = np.zeros(m)
    du2 = np.zeros(m)
    k1y = np.zeros(m)
    k1w = np.zeros(m)
    k1f = np.zeros(m)
    k2y = np.zeros(m)
    k2w = np.zeros(m)
    k2f = np.zeros(m)
    k3y = np.zeros(m)
    k3w = np.zeros(m)
    k3f = np.zeros(m)
    k4y = np.zeros(m)
    k4w = np.zeros(m)
    k4f = np.zeros(m)
    ty = np.zeros(m)
    tw = np.zeros(m)
    tf = np.zeros(m)
    decay = math.exp(-sample_time / tau)
    d_decay = decay * sample_time / (tau * tau) if tau_free else 0.0
    for s in range(seg_start.shape[0]):
        start = seg_start[s]
        stop = seg_stop[s]
        y = initial[s, 0]
        w = initial[s, 1]
        for c in range(m):
            sy[c] = 0.0
            sw[c] = 0.0
            sf[c] = 0.0
        sy[m_cols] = 1.0
        sw[m_cols + 1] = 1.0
        pre = start - int(5.0 * tau / sample_time) if lag_on else start
        if pre < 0:
            pre = 0
        f = 0.0
        for j in range(pre, start + 1):
            e = voltage[j] - r * current[j]
            g = 0.0 if (gate_on and gate_signal[j] < vth) else 1.0
            u = k * e * abs(e) * g
            if j == pre:
                for c in range(m_cols):
                    sf[c] = _thrust_derivative(track[c], k, e, current[j], g)
                f = u
            else:
                for c in range(m_cols):
                    value = decay * sf[c] + (1.0 - decay) * _thrust_derivative(track[c], k, e, current[j], g)
                    if track[c] == LAG_COLUMN:
                        value += d_decay * (f - u)
                    sf[c] = value
                f = decay * f + (1.0 - decay) * u
        i = start
        while True:
            out[0, i] = y + offset
            for c in range(m_cols):
                d_columns[i, c] = sy[c] + (1.0 if track[c] == OFFSET_COLUMN else 0.0)
            d_initial[i, 0] = sy[m_cols]
            d_initial[i, 1] = sy[m_cols + 1]
            if i + stride >= stop:
                break
            g_first = 1.0
            g_second = 1.0
            if gate_on:
                g_first = 0.0 if gate_signal[i] < vth else 1.0
                g_second = 0.0 if gate_signal[i + 1] < vth else 1.0
            e0 = voltage[i] - r * current[i]
            e1 = voltage[i + 1] - r * current[i + 1]
            e2 = voltage[i + 2] - r * current[i + 2]
            g1 = 0.5 * (g_first + g_second)
            u0 = k * e0 * abs(e0) * g_first
            u1 = k * e1 * abs(e1) * g1
            u2 = k * e2 * abs(e2) * g_second
            for c in range(m):
                du0[c] = _thrust_derivative(track[c], k, e0, current[i], g_first)
                du1[c] = _thrust_derivative(track[c], k, e1, current[i + 1], g1)
                du2[c] = _thrust_derivative(track[c], k, e2, current[i + 2], g_second)
            dy1, dw1, df1 = _stage(y, w, f, u0, du0, sy, sw, sf, track, m, a, b, fc, cd, kc, tau, tau_free, smooth,
                                   stiff_friction, lag_on, k1y, k1w, k1f, need_tanh)
            _stage_point(sy, sw, sf, k1y, k1w, k1f, 0.5 * h, m, ty, tw, tf)
            y2 = y + 0.5 * h * dy1
            w2 = w + 0.5 * h * dw1
            f2 = f + 0.5 * h * df1
            dy2, dw2, df2 = _stage(y2, w2, f2, u1, du1, ty, tw, tf, track, m, a, b, fc, cd, kc, tau, tau_free,
                                   smooth, stiff_friction, lag_on, k2y, k2w, k2f, need_tanh)
            _stage_point(sy, sw, sf, k2y, k2w, k2f, 0.5 * h, m, ty, tw, tf)
            y3 = y + 0.5 * h * dy2
            w3 = w + 0.5 * h * dw2
            f3 = f + 0.5 * h * df2
            dy3, dw3, df3 = _stage(y3, w3, f3, u1, du1, ty, tw, tf, track, m, a, b, fc, cd, kc, tau, tau_free,
                                   smooth, stiff_friction, lag_on, k3y, k3w, k3f, need_tanh)
            _stage_point(sy, sw, sf, k3y, k3w, k3f, h, m, ty, tw, tf)
            y4 = y + h * dy3
            w4 = w + h * dw3
            f4 = f + h * df3
            dy4, dw4, df4 = _stage(y4, w4, f4, u2, du2, ty, tw, tf, track, m, a, b, fc, cd, kc, tau, tau_free,
                                   smooth, stiff_friction, lag_on, k4y, k4w, k4f, need_tanh)
            y = y + h / 6.0 * (dy1 + 2.0 * dy2 + 2.0 * dy3 + dy4)
            w = w + h / 6.0 * (dw1 + 2.0 * dw2 + 2.0 * dw3 + dw4)
            for c in range(m):
                sy[c] += h / 6.0 * (k1y[c] + 2.0 * k2y[c] + 2.0 * k3y[c] + k4y[c])
                sw[c] += h / 6.0 * (k1w[c] + 2.0 * k2w[c] + 2.0 * k3w[c] + k4w[c])
            if lag_on:
                f = f + h / 6.0 * (df1 + 2.0 * df2 + 2.0 * df3 + df4)
                for c in range(m):
                    sf[c] += h / 6.0 * (k1f[c] + 2.0 * k2f[c] + 2.0 * k3f[c] + k4f[c])
            i += stride


__all__ = ['EXACT_COLUMNS', 'friction_term', 'sensitivity_kernel']
