"""Weak SINDy (WSINDy) for ordinary differential equations, split by role.

- :mod:`~aeropend_core.wsindy.library` — candidate terms θ_j (products, powers, sin/cos, held inputs).
- :mod:`~aeropend_core.wsindy.test_functions` — φ, its power and half-width, the quadrature kernels.
- :mod:`~aeropend_core.wsindy.quadrature` — segments, test-function grid, weak rows, whitening.
- :mod:`~aeropend_core.wsindy.noise_model` — GLS noise model: noise levels, residual covariance, compensation.
- :mod:`~aeropend_core.wsindy.selection` — MSTLS with automatic λ, greedy paths, exhaustive small supports.
- :mod:`~aeropend_core.wsindy.weak_form` — the entry point :func:`~aeropend_core.wsindy.weak_form.fit_weak_sindy`
  and its result types (the method is described in that module's docstring and in ``docs/method.md``).
"""
