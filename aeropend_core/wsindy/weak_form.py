"""Weak SINDy (WSINDy) for ordinary differential equations, written from the method (Messenger & Bortz).

For each equation ``d^k x/dt^k = Σ_j w_j θ_j(signals)`` and each test function φ supported on 2m+1 samples, the
weak form integrates by parts until no derivative of data is left::

    (-1)^k ∫ φ^(k) x dt  =  Σ_j w_j ∫ φ θ_j dt          (a term with its own derivative order d
                                                           contributes (-1)^d ∫ φ^(d) θ_j dt)

which gives a linear system ``G w = b`` (one row per test function). Steps:

1. Test functions φ(t) = (1 − ((t − c)/(m Δt))²)^p; p is the smallest power that makes φ decay below
   ``decay_tolerance`` at the first interior sample; the half-width m comes from the target signal's spectrum:
   the corner wavenumber k* of its cumulative Fourier magnitude (two-piece linear fit) and
   ``2π k* m = spectral_width · N · sqrt(2p + 3)`` (φ's spectrum then falls off where the data's noise floor
   starts). m and p are solved together, m clipped to [``min_half_width``, ``max_half_width``].
2. Gram matrix and right-hand side by trapezoid quadrature: all test functions are shifts of one kernel, so the
   integrals are a strided correlation of each library column with the kernel (vectorised, no dense V).
   Terms marked ``hold`` (zero-order-hold inputs, interval quantities) use the midpoint of each sample interval
   instead: the trapezoid rule would shift a held input by half a sample (~1 % bias in gains and damping).
3. Generalised least squares: white noise on the target makes the rows of b correlated with covariance
   ∝ V^(k) V^(k)ᵀ; both sides are whitened with its (banded) Cholesky factor. Then the covariance is rebuilt
   from the linearised response of the whole residual b − Gw to white noise on every signal (including noise
   entering the library terms, with the current w) and the fit is repeated (``irls_iterations``), as in the
   reference WSINDy; without this the whitening amplifies low-frequency regressor noise and biases every
   coefficient (4 % on the pendulum with a 10-bit angle). In the reweighted passes the normal equations are
   also bias-compensated (``bias_correction``): the expected contribution of the noise to G̃ᵀG̃ and G̃ᵀb̃,
   computed from the per-signal noise levels (robust third-difference estimate unless given), is subtracted.
   Noisy regressors otherwise attenuate coefficients (errors in variables; -10 to -25 % on Kq at 30 dB).
   The reweighted covariance also gets a 'process noise' term q·V Vᵀ (``process_noise``), q estimated from the
   previous residual: for a second-order equation the measurement-only whitening integrates the equation twice,
   so an unmodelled force (pivot friction) would otherwise swamp the fit.
4. Modified sequential thresholding (MSTLS) in scale-free coordinates: with columns and b normalised, a term is
   kept while its relative contribution ``|w_i|·‖G_i‖/‖b‖`` lies in [λ, 1/λ]; refit on the kept terms until the
   set is stable. λ is chosen on a log grid 10^[-4..0] (100 values) by minimising
   ``L(λ) = 2α ‖G(w_λ − w_LS)‖/‖G w_LS‖ + 2(1 − α) nnz(w_λ)/J`` (α = 0.8), smallest minimiser. A small ridge
   (relative to the normalised Gram matrix) keeps nearly collinear libraries (sin y vs y) solvable during the
   thresholding; the kept terms are refitted without it. Because thresholding can drop a true term of a nearly
   collinear group early, the supports of a greedy backward elimination, a greedy forward selection and every
   support of up to ``exhaustive_terms`` terms are scored with the same loss L too; the best is refined by
   single additions/removals while L drops; the overall minimiser wins (λ reported as NaN when it is not on
   the MSTLS path).
5. Standard errors of the kept coefficients: the significance guard uses the model-based σ̂² (G̃ᵀG̃ − C)⁻¹
   (σ̂² = ‖r‖²/(n_rows − n_kept), C the noise compensation, when used); the reported covariance is the sandwich
   B M B with B = (G̃ᵀG̃ − C)⁻¹ and M the block sums of the scores G̃_i r̃_i (Bartlett, Andrews' width), because
   the whitened residual rows stay correlated (:func:`aeropend_core.wsindy.noise_model._sandwich_covariance`).

Test-function centres are ``stride`` = m/4 samples apart (overlapping supports; the GLS covariance accounts
for the overlap). Heavy loops (support selection, banded covariance, band of Σ⁻¹) are numba kernels cached on
disk, so the first call in a fresh environment compiles for a few seconds.

Several experiments or segments are fitted together by stacking their (separately whitened) weak equations.

The public entry point is :func:`fit_weak_sindy`; the candidate terms come from :mod:`aeropend_core.wsindy.library`.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, special
from threadpoolctl import ThreadpoolController

from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.parallel import default_workers, map_in_order
from aeropend_core.wsindy.library import Term
from aeropend_core.wsindy.noise_model import (
    _cached,
    _banded_lower_solve,
    _cholesky_band,
    _coefficient_covariance,
    _sandwich_covariance,
    _measurement_band,
    _noise_gram,
    _noise_model,
    _process_band,
)
from aeropend_core.wsindy.quadrature import _as_segments, _centres, _median, _weak_rows
from aeropend_core.wsindy.selection import _regress
from aeropend_core.wsindy.test_functions import (
    choose_support,
    kernel_derivatives,
    kernel_hold,
    test_function_power,
)


@dataclass(frozen=True)
class Equation:
    """One equation to identify: ``d^order target / dt^order = Σ w_j · term_j``.

    Parameters
    ----------
    target : str [-]
        Name of the signal whose derivative is the left-hand side.
    terms : sequence of Term [-]
        Candidate terms (:mod:`aeropend_core.wsindy.library`).
    order : int [-]
        Derivative order of the left-hand side (1 for first-order systems, 2 for the pendulum from the angle).
    keep : sequence of str [-]
        Names of terms never thresholded away (known structure); others are subject to MSTLS.

    Examples
    --------
    >>> from aeropend_core import Equation
    >>> from aeropend_core.wsindy import library
    >>> equation = Equation('x', library.polynomial(['x'], degree=1))     # dx/dt = c0 + c1 x
    >>> equation.name
    'dx/dt'
    """

    target: str
    terms: tuple[Term, ...]
    order: int = 1
    keep: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, 'terms', tuple(self.terms))
        object.__setattr__(self, 'keep', tuple(self.keep))
        if self.order < 1:
            raise AeropendError(f'equation for {self.target!r}: order must be >= 1, got {self.order}')
        names = [t.name for t in self.terms]
        if not names:
            raise AeropendError(f'equation for {self.target!r} has no candidate terms')
        if len(set(names)) != len(names):
            raise AeropendError(f'equation for {self.target!r} has duplicate term names: {names}')
        unknown = set(self.keep) - set(names)
        if unknown:
            raise AeropendError(f'equation for {self.target!r}: keep names {sorted(unknown)} are not terms')

    @property
    def name(self) -> str:
        """Left-hand side, e.g. ``'dangle/dt'`` or ``'d^2angle/dt^2'``."""
        return f'd{self.target}/dt' if self.order == 1 else f'd^{self.order}{self.target}/dt^{self.order}'


@dataclass(frozen=True, eq=False)
class EquationFit:
    """Result for one equation. Coefficients are in the units of (lhs unit) / (term unit).

    Attributes
    ----------
    name : str
        Left-hand side (:attr:`Equation.name`).
    candidates : tuple of str
        All candidate term names, in library order.
    coefficients : dict
        Selected term name -> coefficient (terms not selected are absent).
    standard_errors : dict
        Selected term name -> 1σ standard error of the coefficient.
    covariance : ndarray, shape (n_selected, n_selected)
        Coefficient covariance, in the order of ``coefficients``.
    threshold : float
        The λ used (0.0 when thresholding was off; NaN when a greedy (backward/forward) support won).
    residual : float
        Relative whitened residual ‖G̃w − b̃‖/‖b̃‖ (0 = perfect fit).
    half_width, power, n_test_functions : int
        Test-function half-width m (samples), power p, and number of weak equations (rows) used.
    model_standard_errors : dict
        The model-based σ (white whitened residual) that the significance guard uses, for a caller that ranks or
        selects terms the same way (units as ``standard_errors``); ``standard_errors`` is the one to report.
    """

    name: str
    candidates: tuple[str, ...]
    coefficients: dict[str, float]
    standard_errors: dict[str, float]
    covariance: np.ndarray = field(repr=False)
    threshold: float
    residual: float
    half_width: int
    power: int
    n_test_functions: int
    model_standard_errors: dict[str, float] = field(default_factory=dict)

    @property
    def selected(self) -> tuple[str, ...]:
        """Names of the terms kept."""
        return tuple(self.coefficients)

    def coefficient(self, term: str) -> float:
        """Coefficient of ``term`` (0.0 if the term was not selected; KeyError if it was no candidate)."""
        if term not in self.candidates:
            raise KeyError(f'{term!r} is not a candidate of {self.name}; candidates: {list(self.candidates)}')
        return self.coefficients.get(term, 0.0)

    def format(self) -> str:
        """``lhs = c1·term1 + c2·term2 ...`` with ±1σ."""
        if not self.coefficients:
            return f'{self.name} = 0'
        parts = [f'({c:+.6g} ± {self.standard_errors[k]:.2g})·{k}' for k, c in self.coefficients.items()]
        return f'{self.name} = ' + ' + '.join(parts)


@dataclass(frozen=True, eq=False)
class WeakSindyResult:
    """Identified equations, in the order requested. Index by left-hand side name or by target signal.

    Parameters
    ----------
    equations : tuple of EquationFit [-]
        One per requested equation: coefficients in (left-hand side unit) / (term unit), with 1σ.

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import Equation, fit_weak_sindy
    >>> from aeropend_core.wsindy import library
    >>> time = np.arange(0.0, 5.0, 0.002)                                                     # s
    >>> result = fit_weak_sindy(time, {'x': np.exp(-2 * time)}, [Equation('x', library.polynomial(['x'], degree=1))])
    >>> result.summary()['dx/dt']['terms'], round(result.to_dict()['dx/dt']['coefficients']['x'], 2)     # 1/s
    (['x'], -2.0)
    >>> result.as_text() == result.format(), result.as_html().startswith('<section')
    (True, True)
    """

    equations: tuple[EquationFit, ...]

    def __getitem__(self, key: str) -> EquationFit:
        for eq in self.equations:
            if key == eq.name or eq.name in (f'd{key}/dt',) or eq.name.endswith(f'{key}/dt^2'):
                return eq
        raise KeyError(f'no equation {key!r}; have {[e.name for e in self.equations]}')

    @property
    def coefficients(self) -> dict[str, dict[str, float]]:
        """lhs name -> {term: coefficient}."""
        return {eq.name: dict(eq.coefficients) for eq in self.equations}

    @property
    def standard_errors(self) -> dict[str, dict[str, float]]:
        """lhs name -> {term: 1σ standard error}."""
        return {eq.name: dict(eq.standard_errors) for eq in self.equations}

    def format(self) -> str:
        """The equations, one a line: ``lhs = (c ± σ)·term + ...`` (:meth:`as_text`)."""
        return '\n'.join(eq.format() for eq in self.equations)

    # the result presents itself (words in present/results_text.py, imported when called; the package example runs
    # these)
    def summary(self) -> dict:
        """Per equation: the terms kept, the relative residual [-], the weak equations used [-]."""
        from aeropend_core.present.results_text import weak_sindy_summary
        return weak_sindy_summary(self)

    def as_text(self) -> str:
        """The equations with their coefficients ± 1σ, one a line (as :meth:`format`)."""
        return self.format()

    def as_html(self) -> str:
        """The equations as a self-contained HTML fragment (``<section>``, text escaped)."""
        from aeropend_core.present.results_text import text_html
        return text_html(self.format(), 'Weak SINDy: identified equations', 'aeropend-weak-sindy')

    def to_dict(self) -> dict:
        """Per equation: coefficients and 1σ ((lhs unit) / (term unit)), candidates, threshold, residual [-],
        test functions' half-width [samples] and power [-]."""
        from aeropend_core.present.results_text import weak_sindy_dict
        return weak_sindy_dict(self)


# ------------------------------------------------------------------------------------------------- main API
_BLAS: list = []


@dataclass(frozen=True)
class WeakSindyOptions:
    """The settings of :func:`fit_weak_sindy`, held once (as pysindy's optimisers hold their hyper-parameters).

    Parameters
    ----------
    half_width : int or mapping target -> int, optional [samples]
        Test-function half-width m (support 2m+1). Default (or targets missing from the mapping): chosen per
        equation from the target signal's spectrum (:func:`choose_support`, median over segments).
    stride : int, optional [samples]
        Samples between test-function centres; default max(1, m // 4).
    threshold : 'auto', float in (0, 1] or None, dimensionless
        MSTLS λ: 'auto' searches the grid 10^[-4..0]; a number fixes it; None gives the plain (ridge) GLS fit
        of all candidates (no sparsification).
    ridge : float, dimensionless
        Tikhonov term added to the normalised (unit-diagonal) Gram matrix.
    alpha : float, dimensionless
        Weight of accuracy vs sparsity in the λ loss.
    decay_tolerance : float, dimensionless
        φ at the first interior sample of its support must fall below this (sets the power p).
    spectral_width : float, dimensionless
        Scale of the half-width chosen from the spectrum's corner (see :func:`choose_support`).
    min_half_width, max_half_width : int [samples]
        Bounds of the half-width chosen from the spectrum.
    noise_std : mapping signal -> float, optional [unit of each signal]
        Measurement-noise standard deviation per signal, for the residual covariance. Signals not given are
        estimated from the data (:func:`estimate_noise_std`); give 0 for an exactly known signal.
    irls_iterations : int [-]
        Reweighting passes: after a first fit with Σ ∝ V^(k)V^(k)ᵀ (noise on the target only), Σ is rebuilt from
        the linearised response of the whole residual to the noise on every signal (target, derivative terms,
        nonlinear terms) and the fit repeated. This removes most of the errors-in-variables bias that a
        target-only whitening causes (it amplifies low-frequency noise in the regressors). One pass (default)
        is enough: a second one changed no support and no error by more than noise (full state: Kq rms error
        0.14 % at 50 dB, 1.48 % -> 1.37 % at 30 dB; live rig at 40 dB: worst parameter 2.1 % -> 1.5 %, with one
        pass; 4 to 8 records each) and costs a third more time.
    bias_correction : bool [-]
        Subtract the expected noise contributions from the normal equations (bias-compensated least squares,
        :func:`_noise_gram`), using the per-signal noise levels; removes the errors-in-variables attenuation.
        Applied in the reweighted passes (so it needs ``irls_iterations >= 1``).
    process_noise : bool [-]
        In the reweighted passes, add q·V Vᵀ to the residual covariance, q ≥ 0 estimated from the previous
        pass's residual (method of moments): unmodelled forces act like noise in the equation itself. With
        q = 0 (an exact model) nothing changes; with a missing effect (e.g. 3 rad/s² of pivot friction) the
        measurement-only whitening would otherwise wipe out the fit (all coefficients -99 %).
    exhaustive_terms : int [-]
        With ``threshold='auto'``, every support of up to this many free terms (besides ``keep``) is scored with
        the loss as well, in the last pass (sum of C(J, k), k <= 4: 3,214 supports for J = 17, depth-first with
        one Cholesky row per added term).
    significance : float, optional, dimensionless
        With thresholding on, drop selected free terms whose |w|/σ_w is below the two-sided normal critical value
        at family-wise level ``significance`` over the J free candidates (Bonferroni: z = Φ⁻¹(1 − s/(2J)),
        2.99 for s = 0.05, J = 18), weakest first, refitting after each removal. None (default) skips the test.

    Examples
    --------
    >>> from aeropend_core.wsindy.weak_form import WeakSindyOptions
    >>> options = WeakSindyOptions(threshold=None)       # a plain GLS fit of every candidate
    >>> options.replace(half_width=40).half_width, options.replace(half_width=40).threshold    # samples, -
    (40, None)
    """

    half_width: int | Mapping[str, int] | None = None
    stride: int | None = None
    threshold: float | str | None = 'auto'
    ridge: float = 1e-6
    alpha: float = 0.8
    decay_tolerance: float = 1e-10
    spectral_width: float = 1.0
    min_half_width: int = 8
    max_half_width: int = 1000
    noise_std: Mapping[str, float] | None = None
    irls_iterations: int = 1
    bias_correction: bool = True
    exhaustive_terms: int = 4
    process_noise: bool = True
    significance: float | None = None

    def replace(self, **changes) -> WeakSindyOptions:
        """A copy with `changes`; an unknown setting is an :class:`AeropendError` naming the known ones."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise AeropendError(f'unknown weak SINDy option(s) {unknown}; the options are '
                                f'{[f.name for f in dataclasses.fields(self)]}')
        return dataclasses.replace(self, **changes) if changes else self


#: Threads fitting the equations of one call side by side (at most AEROPEND_WORKERS or the cores: parallel.py).
EQUATION_WORKERS = 2


def _single_threaded_blas(func):
    """Run ``func`` with BLAS limited to one thread: the products here are small (tens of terms × a few hundred
    rows), and on a 2-core machine a multithreaded BLAS spends more time synchronising than computing (44 ms vs
    65-130 ms per 4-equation window). The controller is created on first use (after NumPy/SciPy loaded BLAS)."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        if not _BLAS:
            _BLAS.append(ThreadpoolController())
        with _BLAS[0].limit(limits=1, user_api='blas'):
            return func(*args, **kwargs)
    return wrapper


@_single_threaded_blas
def fit_weak_sindy(time, signals, equations: Sequence[Equation], options: WeakSindyOptions | None = None, *,
                   exclude=None, **option_changes) -> WeakSindyResult:
    """Identify sparse ODEs from uniformly sampled data with weak SINDy.

    Parameters
    ----------
    time : ndarray, shape (n_samples,) [s]
        Uniform sample times, or a sequence of such arrays, one per segment/experiment.
    signals : mapping name -> ndarray, shape (n_samples,) [SI unit of each signal]
        Or a sequence of mappings, one per segment; every name a term or target uses must be present. Segments
        are fitted together.
    equations : sequence of Equation [-]
        What to identify (targets, derivative orders, candidate terms).
    options : WeakSindyOptions, optional [-]
        The method's settings (test functions, thresholding, noise model); default ``WeakSindyOptions()``.
    exclude : ndarray of bool, shape (n_samples,), or one per segment, optional [-]
        Samples no test-function support may cover (e.g. transients the model does not describe).
    **option_changes : [-]
        Fields of :class:`WeakSindyOptions` to change for this call (``threshold=None``, ``half_width=40``...).

    Returns
    -------
    WeakSindyResult
        One :class:`EquationFit` per equation: selected coefficients [lhs unit / term unit] with 1σ standard
        errors and covariance, λ, relative residual, test-function half-width and power.

    Raises
    ------
    InsufficientDataError
        NaN/inf in the data, a segment shorter than the test-function support, a constant target, or fewer
        usable test functions than candidate terms.
    AeropendError
        Missing signals, non-uniform sampling, bad options.

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import Equation, fit_weak_sindy
    >>> from aeropend_core.wsindy import library
    >>> time = np.arange(0.0, 5.0, 0.002)                                # s; x = exp(-2 t), so dx/dt = -2 x
    >>> result = fit_weak_sindy(time, {'x': np.exp(-2 * time)}, [Equation('x', library.polynomial(['x'], degree=1))])
    >>> round(result['x'].coefficient('x'), 2), result['x'].standard_errors['x'] < 0.01           # 1/s
    (-2.0, True)
    """
    equations = list(equations)
    if not equations:
        raise AeropendError('no equations to identify')
    segments = _as_segments(time, signals)
    if exclude is None:
        excludes = [None] * len(segments)
    elif isinstance(exclude, np.ndarray) and exclude.ndim == 1 and len(segments) == 1:
        excludes = [exclude]
    else:
        excludes = list(exclude)
    dt = _median(np.diff(segments[0][0]))
    for t, _ in segments[1:]:
        if abs(_median(np.diff(t)) - dt) > 1e-3 * dt:
            raise AeropendError('segments have different sample times; resample them to one rate first')
    for eq in equations:
        needed = {eq.target, *(v for t in eq.terms for v in t.variables)}
        for i, (_, s) in enumerate(segments):
            missing = needed - set(s)
            if missing:
                raise AeropendError(f'equation {eq.name} needs signal(s) {sorted(missing)}, not in the data '
                                    f'(have {sorted(s)})')

    cache: dict = {}   # library columns, Jacobians and noise levels shared by the equations (terms keyed by name)
    options = (options or WeakSindyOptions()).replace(**option_changes)
    # the equations are independent (their shared cache holds pure functions of the data: a value two threads make
    # at once is the same value); NumPy, LAPACK and the numba kernels release the GIL. AEROPEND_WORKERS and a map
    # already inside a worker (a diagnosis's round) are respected as by every other side-by-side map
    fits = map_in_order(lambda eq: _fit_equation(eq, segments, excludes, dt, cache, options), equations,
                        min(EQUATION_WORKERS, default_workers()))
    return WeakSindyResult(tuple(fits))


def _fit_equation(eq: Equation, segments, excludes, dt: float, cache: dict,
                  options: WeakSindyOptions) -> EquationFit:
    """One equation of :func:`fit_weak_sindy` (its parameters, same meaning): test functions, weak system,
    GLS passes with the noise model, term selection, significance guard."""
    targets = [s[eq.target] for _, s in segments]
    scale = max(float(np.max(np.abs(x))) for x in targets) or 1.0
    if all(np.ptp(x) <= 1e-12 * scale for x in targets):
        raise InsufficientDataError(f'{eq.target!r} is constant: nothing to identify for {eq.name} '
                                    '(no excitation)')
    # --- test functions
    half_width = options.half_width
    if half_width is None or (isinstance(half_width, Mapping) and eq.target not in half_width):
        choices = [choose_support(x, eq.order, options.decay_tolerance, options.spectral_width,
                                  options.min_half_width, options.max_half_width) for x in targets]
        m = int(statistics.median([c[0] for c in choices]))
    else:
        m = int(half_width[eq.target] if isinstance(half_width, Mapping) else half_width)
        if m < 2:
            raise AeropendError(f'half_width must be >= 2 samples, got {m}')
    p = max(test_function_power(m, options.decay_tolerance), eq.order + 2)
    s_ = int(options.stride or max(1, m // 4))
    max_order = max([eq.order] + [t.derivative_order for t in eq.terms])
    weights = kernel_derivatives(m, p, dt, max_order)
    hold_weights = kernel_hold(m, p, dt)
    # kernel types of the noise model: 0 = lhs (-1)^k φ^(k), then one per term kernel ((-1)^d φ^(d) or hold)
    kernel_ids = [('lhs',)]
    kernel_list = [(-1) ** eq.order * weights[eq.order]]
    type_of = []
    for t_ in eq.terms:
        kid = ('hold',) if t_.hold else ('d', t_.derivative_order)
        if kid not in kernel_ids:
            kernel_ids.append(kid)
            order_ = t_.derivative_order
            kernel_list.append(hold_weights if t_.hold else (-1) ** order_ * weights[order_])
        type_of.append(kernel_ids.index(kid))
    width = 2 * m + 1
    short = [i for i, (t, _) in enumerate(segments) if len(t) < width]
    if short:
        i = short[0]
        raise InsufficientDataError(
            f'{f"segment {i}: " if len(segments) > 1 else ""}window of {len(segments[i][0])} samples '
            f'({len(segments[i][0]) * dt:.3g} s) is shorter than the test-function support for {eq.name}: '
            f'2m+1 = {width} samples ({width * dt:.3g} s); record longer windows')
    systems = []
    for si, ((t, s), excl) in enumerate(zip(segments, excludes)):
        centres = _centres(len(t), m, s_)
        if excl is not None:
            excl = np.asarray(excl, bool)
            hits = np.concatenate([[0], np.cumsum(excl)])
            covered = hits[centres + m + 1] - hits[centres - m]
            centres = centres[covered == 0]
            if centres.size == 0:
                continue
        starts = centres - m
        even = s_ if excl is None else None     # _centres spaces the starts evenly unless samples were excluded
        gb = np.empty((len(starts), len(eq.terms) + 1), order='F')   # [G b], Fortran order for LAPACK
        g = gb[:, :-1]
        for d in sorted({t_.derivative_order for t_ in eq.terms}):
            for held in (False, True):
                idx = [j for j, t_ in enumerate(eq.terms) if t_.derivative_order == d and t_.hold == held]
                if idx:
                    group = tuple((eq.terms[j].name, eq.terms[j].variables) for j in idx)
                    members = [eq.terms[j] for j in idx]
                    theta = _cached(cache, ('thetas', si, group), lambda members=members, s=s, si=si:
                                    np.column_stack([_cached(cache, ('theta', si, term.name, term.variables),
                                                             lambda term=term, s=s: term.evaluate(s))
                                                     for term in members]))
                    kern = hold_weights if held else weights[d]
                    rows = _weak_rows(theta, kern, starts, even)
                    g[:, idx] = -rows if d % 2 else rows      # (−1)^d, exactly
        lhs = _weak_rows(s[eq.target][:, None], weights[eq.order], starts, even)[:, 0]
        gb[:, -1] = -lhs if eq.order % 2 else lhs
        b = gb[:, -1]
        model = _noise_model(eq, s, starts, kernel_list, type_of, options.noise_std, cache, si, width, weights[0])
        systems.append((g, b, model, gb))
    n_rows = sum(len(sys_[1]) for sys_ in systems)
    if n_rows <= len(eq.terms):
        raise InsufficientDataError(
            f'{eq.name}: only {n_rows} usable test functions (support {width} samples) for {len(eq.terms)} '
            'candidate terms; record longer windows or use fewer terms')
    keep = np.array([t_.name in eq.keep for t_ in eq.terms])
    w = None
    for pass_ in range(options.irls_iterations + 1):
        rows_a, rows_b = [], []
        # The first pass (target-only whitening) is not corrected: that whitening amplifies regressor noise
        # so much that the correction itself becomes unstable; it only supplies w for the full covariance.
        correct = options.bias_correction and w is not None
        noise_gram = np.zeros((len(eq.terms), len(eq.terms))) if correct else None
        noise_rhs = np.zeros(len(eq.terms)) if correct else None
        bands = [_measurement_band(model, w) for _, _, model, _ in systems]
        process = 0.0
        if options.process_noise and w is not None:
            # Method of moments: E‖b − Gw‖² = tr Σ_meas + q·tr(V Vᵀ); q > 0 when the model misses forces
            # (friction, cable...). Without it the whitening integrates the equation twice (second order)
            # and any unmodelled low-frequency force swamps the fit.
            resid = sum(float(np.sum((b - g @ w) ** 2)) for g, b, _, _ in systems)
            trace_meas = sum(float(ab[0].sum()) for ab, _ in bands)
            trace_v = sum(len(b) for _, b, _, _ in systems) * float(weights[0] @ weights[0])
            process = max(0.0, (resid - trace_meas) / trace_v)
        for (g, b, model, gb), (ab, band) in zip(systems, bands):
            if process > 0.0:
                ab = ab + _process_band(model, band, process)
            chol = _cholesky_band(ab)
            both = _banded_lower_solve(chol, gb)   # L⁻¹[G b], L banded (gb is not overwritten)
            if both.shape[0] != gb.shape[0]:
                raise InsufficientDataError(f'{eq.name}: the weak-form covariance is singular (a zero pivot of '
                                            'its Cholesky factor); the data cannot support this fit')
            rows_a.append(both[:, :-1])
            rows_b.append(both[:, -1])
            if correct:
                cg, cr = _noise_gram(model, chol, len(eq.terms))
                noise_gram += cg
                noise_rhs += cr
        groups = np.repeat(np.arange(len(rows_a)), [len(r) for r in rows_a])
        a = rows_a[0] if len(rows_a) == 1 else np.vstack(rows_a)
        bw = rows_b[0] if len(rows_b) == 1 else np.concatenate(rows_b)
        # Earlier passes only supply w for the covariance: the greedy paths and the exhaustive search run in
        # the last one (with them in the first pass too, no support and no Kq error changed beyond noise).
        last = pass_ == options.irls_iterations
        w_n, lam, col, bnorm, ata, atb = _regress(a, bw, keep, options.threshold, options.ridge, options.alpha,
                                                  noise_gram, noise_rhs, options.exhaustive_terms if last else 0,
                                                  greedy=last)
        w = w_n * bnorm / col
    sel = np.flatnonzero(w_n)
    cov, resid_vec = _coefficient_covariance(a, bw, w, sel, col, noise_gram, ata)
    if options.significance is not None and options.threshold is not None and sel.size:
        # Significance guard (backward elimination by t-statistic): a selected free term must differ from 0
        # at the family-wise level ``significance`` over the J free candidates (Bonferroni, two-sided normal
        # critical value). The loss-based selection cannot tell a real small term from the best of J noise
        # look-alikes (|t| ~ 2.5 at 40 dB); this test can, with a level chosen before seeing any data.
        free = int(np.count_nonzero(~keep & (col > 0)))
        critical = float(special.ndtri(1.0 - options.significance / (2.0 * max(free, 1))))
        gram_c = ata - (noise_gram if noise_gram is not None else 0.0)
        rhs_c = atb - (noise_rhs if noise_rhs is not None else 0.0)
        while sel.size:
            tstat = np.abs(w[sel]) / np.sqrt(np.maximum(np.diag(cov), 1e-300))
            tstat[keep[sel]] = np.inf
            worst = int(np.argmin(tstat))
            if tstat[worst] >= critical:
                break
            sel = np.delete(sel, worst)
            w = np.zeros_like(w)
            if sel.size:
                cs = col[sel]   # column-normalised, as in the selection
                w[sel] = linalg.solve(gram_c[np.ix_(sel, sel)] / np.outer(cs, cs), rhs_c[sel] / cs,
                                      assume_a='sym', check_finite=False) / cs
            cov, resid_vec = _coefficient_covariance(a, bw, w, sel, col, noise_gram, ata)
    model_cov = cov
    if sel.size:     # the reported sigma: honest under correlated whitened residuals (the guard above keeps its own)
        cov = _sandwich_covariance(a, resid_vec, sel, cov, groups)
    names = [eq.terms[j].name for j in sel]
    return EquationFit(
        name=eq.name,
        candidates=tuple(t_.name for t_ in eq.terms),
        coefficients={nm: float(w[j]) for nm, j in zip(names, sel)},
        standard_errors={nm: float(math.sqrt(max(cov[i, i], 0.0))) for i, nm in enumerate(names)},
        covariance=cov,
        threshold=lam,
        residual=float(np.linalg.norm(resid_vec) / (np.linalg.norm(bw) or 1.0)),
        half_width=m, power=p, n_test_functions=n_rows,
        model_standard_errors={nm: float(math.sqrt(max(model_cov[i, i], 0.0))) for i, nm in enumerate(names)})
