"""The discovery stage's terms inside the compiled output-error kernel (numba), so that proving a term is as fast
as proving a catalog effect.

Each simulated term of :data:`aeropend_core.diagnosis.discovery.VOCABULARY` has a code (:data:`TERM_CODES`, by
slug); :func:`term_value` evaluates ``term(angle, angular_rate, thrust)`` for a code inside the kernel. The Python
functions of the vocabulary and these agree (tests/test_discovery.py checks every code).
"""
from __future__ import annotations

import math

import numba

from aeropend_core.model.effects import FRICTION_SMOOTHING

#: Code of each simulated vocabulary term, by slug (-1 in the kernel: no term).
TERM_CODES = {slug: code for code, slug in enumerate((
    'constant', 'cos_angle', 'angle', 'angle_square', 'angle_cube', 'sin_2angle', 'cos_2angle', 'sin_3angle',
    'rate_sign', 'rate_square', 'rate_power_0p5', 'rate_power_1p5', 'rate_power_3', 'stribeck_0p05', 'stribeck_0p1',
    'stribeck_0p2', 'stribeck_0p4', 'thrust_rate', 'speed_rate', 'thrust_angle', 'thrust_cos', 'thrust_square'))}


@numba.njit(cache=True, nogil=True)
def term_value(code: int, y: float, w: float, u: float) -> float:
    """Value of term `code` at angle `y` [rad], rate `w` [rad/s] and thrust acceleration `u` [rad/s^2] (0 for -1).

    Parameters
    ----------
    code : int [-]
        The term's code (:data:`TERM_CODES`), or -1.
    y, w, u : float [rad, rad/s, rad/s^2]
        The state and the thrust's angular acceleration.

    Returns
    -------
    float
        The term's value [its unit].
    """
    if code < 0:
        return 0.0
    sign = 1.0 if w > 0 else (-1.0 if w < 0 else 0.0)
    smooth = math.tanh(w / FRICTION_SMOOTHING)
    if code == 0:
        return 1.0
    if code == 1:
        return math.cos(y)
    if code == 2:
        return y
    if code == 3:
        return y * y
    if code == 4:
        return y * y * y
    if code == 5:
        return math.sin(2.0 * y)
    if code == 6:
        return math.cos(2.0 * y)
    if code == 7:
        return math.sin(3.0 * y)
    if code == 8:
        return smooth
    if code == 9:
        return w * abs(w)
    if code == 10:
        return math.sqrt(abs(w)) * sign
    if code == 11:
        return abs(w) ** 1.5 * sign
    if code == 12:
        return abs(w) ** 3 * sign
    if code == 13:
        return math.exp(-(w / 0.05) ** 2) * smooth
    if code == 14:
        return math.exp(-(w / 0.1) ** 2) * smooth
    if code == 15:
        return math.exp(-(w / 0.2) ** 2) * smooth
    if code == 16:
        return math.exp(-(w / 0.4) ** 2) * smooth
    if code == 17:
        return u * w
    if code == 18:
        return math.sqrt(abs(u)) * w
    if code == 19:
        return u * y
    if code == 20:
        return u * math.cos(y)
    if code == 21:
        return u * u
    return 0.0
