"""Helpers shared by the benchmark scripts: the full-state identification problem, its truth and scores, the pysindy
baselines, timing, machine description and the ``--json`` figures file that ``bench/run_all.py`` collects.

The scripts import it as ``from _common import ...`` (Python puts a script's own folder first on ``sys.path``).
pysindy, threadpoolctl and ROS are imported inside the functions that need them.
"""
from __future__ import annotations

import json
import math
import os
import platform
import statistics
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from aeropend_core.present.json_output import finite_json
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.identify.pendulum import full_state_library, identify_full_state
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.noise import add_noise
from aeropend_core.sim.simulate import simulate
from aeropend_core.wsindy.noise_model import clear_caches

STATES = ('armature_current', 'motor_speed', 'angle', 'angular_rate')
SIGNALS = STATES + ('armature_voltage',)


# ---------------------------------------------------------------------------------------------------------------
# The paper's full-state problem and its truth
# ---------------------------------------------------------------------------------------------------------------

def true_coefficients() -> dict[str, dict[str, float]]:
    """The nominal model written in the library's terms (positive motor speed), SI units per equation."""
    ra, la, kw, kt = P.armature_resistance, P.armature_inductance, P.back_emf_constant, P.torque_constant
    jm, fr, kd, g = P.motor_inertia, P.motor_friction, P.propeller_torque_coefficient, P.gear_ratio
    return {
        'armature_current': {'armature_current': -ra / la, 'motor_speed': -kw / la, 'armature_voltage': 1 / la},
        'motor_speed': {'armature_current': kt / jm, 'motor_speed': -fr / jm, 'motor_speed^2': -kd / g ** 3 / jm},
        'angle': {'angular_rate': 1.0},
        'angular_rate': {'sin(angle)': -P.gravity_stiffness, 'angular_rate': -P.damping,
                         'motor_speed^2': P.lever_per_inertia * P.thrust_coefficient / g ** 2},
    }


def kq_error(coefficients: dict[str, dict[str, float]]) -> float:
    """|relative error| of Kq computed from the ω1² coefficient of dΩ/dt (1.0 when the term is missing)."""
    kq = coefficients['angular_rate'].get('motor_speed^2', 0.0) * P.gear_ratio ** 2 / P.lever_per_inertia
    return abs(kq / P.thrust_coefficient - 1)


def score(coefficients: dict[str, dict[str, float]]) -> tuple[int, float, float]:
    """(wrong terms, |Kq error|, largest relative error of a true coefficient)."""
    truth = true_coefficients()
    wrong, worst = 0, 0.0
    for eq, true in truth.items():
        got = {k: v for k, v in coefficients[eq].items() if v != 0.0}
        wrong += len(set(got) ^ set(true))
        for term, value in true.items():
            worst = max(worst, abs(got.get(term, 0.0) / value - 1))
    return wrong, kq_error(coefficients), worst


def equation_error(coefficients: dict[str, float], equation: str) -> float:
    """Relative L2 error of one equation's coefficient vector: ‖ξ̂ − ξ‖₂ / ‖ξ‖₂ over all library terms."""
    true = true_coefficients()[equation]
    terms = set(true) | set(coefficients)
    diff = math.sqrt(sum((coefficients.get(k, 0.0) - true.get(k, 0.0)) ** 2 for k in terms))
    return diff / math.sqrt(sum(v ** 2 for v in true.values()))


def coefficient_error(coefficients: dict[str, dict[str, float]]) -> float:
    """The benchmarks' coefficient error: the largest over the four equations of the relative L2 error
    ‖ξ̂ₑ − ξₑ‖₂ / ‖ξₑ‖₂ (each equation on its own scale; the whole-matrix norm would only see dω1/dt's 4404·Ia)."""
    return max(equation_error(coefficients[eq], eq) for eq in STATES)


def matrix_error(coefficients: dict[str, dict[str, float]]) -> float:
    """Relative Frobenius error of the whole coefficient matrix ‖Ξ̂ − Ξ‖_F / ‖Ξ‖_F (dominated by dω1/dt)."""
    truth = true_coefficients()
    num = den = 0.0
    for eq in STATES:
        true, got = truth[eq], coefficients[eq]
        num += sum((got.get(k, 0.0) - true.get(k, 0.0)) ** 2 for k in set(true) | set(got))
        den += sum(v ** 2 for v in true.values())
    return math.sqrt(num / den)


def make_window(seed: int, psnr_db: float, duration: float = 10.0) -> dict[str, np.ndarray]:
    """One simulated LHC window at 490 Hz with PSNR `psnr_db` on every signal: ``t`` [s] and SIGNALS (SI)."""
    schedule = lhc_schedule(duration, seed=seed)
    trajectory = simulate(schedule.duty(SAMPLE_TIME, duration), seed=seed)
    rng = np.random.default_rng(1000 + seed)
    data = {'t': trajectory.time}
    for name in SIGNALS:
        data[name] = add_noise(trajectory.truth[name], psnr_db, rng)
    return data


# ---------------------------------------------------------------------------------------------------------------
# aeropend's WSINDy
# ---------------------------------------------------------------------------------------------------------------

#: The plain method: GLS with Σ ∝ V'V'ᵀ only, no bias compensation, MSTLS plus the greedy paths, no exhaustive
#: small-support search, no significance guard.
PLAIN = {'irls_iterations': 0, 'bias_correction': False, 'exhaustive_terms': 0, 'significance': None}

#: Va offered to every equation: exactly the 18-term library pysindy gets.
SAME_LIBRARY = {'voltage_in': STATES}


def run_ours(data, repeats: int, statistic: Callable = statistics.median,
             **options) -> tuple[float, dict[str, dict[str, float]]]:
    """(`statistic` (median) of the seconds per window, coefficients) of identify_full_state; kernel caches cleared
    before each call."""
    identify_full_state(data, **options)  # warm-up (numba kernels load from their cache)
    times = []
    for _ in range(repeats):
        clear_caches()   # no quadrature/pair kernels carried over from the previous (identical) window
        t0 = time.perf_counter()
        fit = identify_full_state(data, **options)
        times.append(time.perf_counter() - t0)
    return statistic(times), {s: dict(fit.result[s].coefficients) for s in STATES}


# ---------------------------------------------------------------------------------------------------------------
# pysindy baselines (same 18 terms, same data)
# ---------------------------------------------------------------------------------------------------------------

def pysindy_library():
    """(pysindy CustomLibrary of the 18 full-state terms as functions of the five signals, term names)."""
    import pysindy as ps
    names, functions = [], []

    def make(term):
        # exactly five positional parameters (pysindy counts them): the signals x..., u in SIGNALS order
        def f(ia, w1, y, om, va):
            return term.evaluate({'armature_current': ia, 'motor_speed': w1, 'angle': y, 'angular_rate': om,
                                  'armature_voltage': va})

        def name(*_args):
            return term.name
        return f, name

    for term in full_state_library():
        f, name = make(term)
        functions.append(f)
        names.append(name)
    return ps.CustomLibrary(library_functions=functions, function_names=names, interaction_only=True), \
        [t.name for t in full_state_library()]


#: STLSQ thresholds tried for the pysindy baselines (absolute, on normalised columns): half-decades 1e-2 .. 1e8;
#: the top one empties every equation, so "no term" is always among the choices.
THRESHOLD_GRID = [10.0 ** (k / 2) for k in range(-4, 17)]


def fit_pysindy(data, threshold: float, form: str = 'weak') -> dict[str, dict[str, float]]:
    """Fit pysindy on `data` with STLSQ(threshold, normalised columns); coefficients per equation.

    form 'weak': WeakPDELibrary over the custom library (K = 100 test functions, p = 4), NumPy's global RNG
    seeded (it draws the test-function centres). form 'strong': plain SINDy with FiniteDifference (2nd order)
    derivatives of the noisy states.
    """
    import pysindy as ps
    custom, names = pysindy_library()
    x = np.column_stack([data[s] for s in STATES])
    u = data['armature_voltage'][:, None]
    optimizer = ps.STLSQ(threshold=threshold, alpha=1e-8, normalize_columns=True)
    if form == 'weak':
        library = ps.WeakPDELibrary(function_library=custom, spatiotemporal_grid=data['t'], K=100, p=4)
        model = ps.SINDy(feature_library=library, optimizer=optimizer)
    elif form == 'strong':
        model = ps.SINDy(feature_library=custom, optimizer=optimizer, differentiation_method=ps.FiniteDifference())
    else:
        raise ValueError(f"form must be 'weak' or 'strong', not {form!r}")
    np.random.seed(0)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        model.fit(x, t=data['t'], u=u)
    coef = model.coefficients()
    features = model.get_feature_names()
    if list(features) != names:  # pysindy must see exactly our library
        raise RuntimeError(f'pysindy library differs: {features[:5]}... vs {names[:5]}...')
    return {eq: {names[j]: float(coef[i, j]) for j in range(len(names)) if coef[i, j] != 0.0}
            for i, eq in enumerate(STATES)}


def pysindy_with_truth(data, form: str = 'weak', grid=None) -> dict:
    """pysindy (`form` 'weak' or 'strong') fitted at every threshold of `grid`; the best one chosen WITH THE TRUTH.

    Per equation: the lowest relative L2 coefficient error of that equation (:func:`equation_error`), then the
    fewest terms (STLSQ treats the equations independently, so one grid serves all four; the top of the grid empties
    an equation, error 1.0, so a baseline's chosen error never exceeds 1). Returns ``coefficients`` and
    ``thresholds`` of that per-equation choice, ``threshold`` (the one chosen for dΩ/dt, used for timing) and
    ``single`` (the best one threshold for all four equations: lowest :func:`coefficient_error`, then fewest wrong
    terms).
    """
    fits = {}
    for threshold in (THRESHOLD_GRID if grid is None else grid):
        try:
            fits[threshold] = fit_pysindy(data, threshold, form)
        except (ValueError, RuntimeError, np.linalg.LinAlgError):   # e.g. a threshold that kills every term
            continue
    if not fits:
        raise RuntimeError(f'pysindy {form}: no threshold of the grid produced a fit')
    chosen, coefficients = {}, {}
    for eq in STATES:
        best = min(fits, key=lambda thr: (equation_error(fits[thr][eq], eq), len(fits[thr][eq])))
        chosen[eq], coefficients[eq] = best, fits[best][eq]
    single = min(fits, key=lambda thr: (coefficient_error(fits[thr]), score(fits[thr])[0]))
    return {'coefficients': coefficients, 'thresholds': chosen, 'threshold': chosen['angular_rate'],
            'single': {'threshold': single, 'coefficients': fits[single]}}


def time_both_blas(function: Callable[[], object], repeats: int,
                   statistic: Callable = statistics.median) -> dict[str, float]:
    """`statistic` (median) of the seconds of `function()` with the default BLAS threads and with one BLAS thread
    (one warm-up each)."""
    from threadpoolctl import threadpool_limits
    timings = {}
    for label, limit in (('default BLAS threads', None), ('1 BLAS thread', 1)):
        with threadpool_limits(limits=limit):
            function()
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                function()
                times.append(time.perf_counter() - t0)
        timings[label] = statistic(times)
    return timings


# ---------------------------------------------------------------------------------------------------------------
# Results files
# ---------------------------------------------------------------------------------------------------------------

def figure(name: str, value: float, units: str, *, baseline: float | None = None, baseline_name: str = '',
           ratio: float | None = None, ratio_meaning: str = '', target: str = '', met: bool | None = None) -> dict:
    """One key figure of a benchmark for the ``--json`` file (ratio = value/baseline unless given)."""
    if ratio is None and baseline not in (None, 0) and value is not None:
        ratio = value / baseline
    return {'name': name, 'value': value, 'units': units, 'baseline': baseline, 'baseline_name': baseline_name,
            'ratio': ratio, 'ratio_meaning': ratio_meaning, 'target': target, 'met': met}


def write_json(path: str | os.PathLike | None, benchmark: str, figures: list[dict], **details) -> None:
    """Write ``{'benchmark', 'figures', 'details', 'load_average'}`` to `path` (nothing when `path` is None)."""
    if path is None:
        return
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {'benchmark': benchmark, 'figures': figures, 'details': details,
              'load_average_at_end': list(os.getloadavg())}
    out.write_text(json.dumps(finite_json(record), indent=1, ensure_ascii=False) + '\n', encoding='utf-8')


def add_json_argument(parser) -> None:
    parser.add_argument('--json', metavar='PATH', default=None,
                        help='also write the key figures (value, baseline, ratio, units, target) to this JSON file')


def machine_info() -> dict:
    """CPU model, cores, RAM, OS, Python and the numeric libraries' versions."""
    from importlib import metadata
    cpu = ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    ram = None
    try:
        for line in Path('/proc/meminfo').read_text().splitlines():
            if line.startswith('MemTotal:'):
                ram = int(line.split()[1]) * 1024
                break
    except OSError:
        pass
    os_name = platform.platform()
    try:
        for line in Path('/etc/os-release').read_text().splitlines():
            if line.startswith('PRETTY_NAME='):
                os_name = f'{line.split("=", 1)[1].strip(chr(34))} (kernel {platform.release()})'
    except OSError:
        pass
    versions = {}
    for package in ('numpy', 'scipy', 'pysindy', 'numba', 'matplotlib'):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {'cpu': cpu or platform.processor(), 'cores': os.cpu_count(), 'ram_bytes': ram,
            'ram_gib': round(ram / 2 ** 30, 1) if ram else None, 'os': os_name,
            'python': platform.python_version(), 'ros_distro': os.environ.get('ROS_DISTRO'), 'versions': versions}


def named_and_confounded(found) -> tuple[list[str], list[str]]:
    """(the effects a diagnosis names with confidence, the effects it names only as confounded) [effect names].

    Confounded: with another catalog effect (``Found.confounded_with``), or with a discovered term outside the
    catalog that explains the record as well in the effect's place (the verdict then says "EFFECT or, in its place,
    the term ...; ... this data cannot tell which": not named with confidence). Counted so since s26 by
    bench/second_rig.py and since s27 by bench/remainder.py (one predicate for both).
    """
    from aeropend_core.present.discovery_text import lookalike_terms
    twins = lookalike_terms(found.discovery)
    named = [f.effect for f in found.found if not f.confounded_with and f.effect not in twins]
    confounded = [f.effect for f in found.found if f.confounded_with or f.effect in twins]
    return named, confounded


def spawn_map(function: Callable, jobs: list, workers: int, each: Callable | None = None) -> tuple[list, float]:
    """(`function` applied to each job on `workers` spawned processes, in order; the wall time [s] it took).
    `each`, when given, is called with every row as it arrives (a long run shows its progress)."""
    import time
    from multiprocessing import get_context
    started = time.perf_counter()
    rows = []
    with get_context('spawn').Pool(workers) as pool:
        for row in pool.imap(function, jobs, chunksize=1):
            rows.append(row)
            if each is not None:
                each(row)
    return rows, time.perf_counter() - started

