"""aeropend_core: the science and I/O of the aeropendulum rig, without ROS.

Folders follow the data flow, from a recording to a verdict:

=================  ===========================================================================================
``io``             recordings in and out: CSV and MCAP bags (:func:`load_recording`, bag writer/reader/recovery)
``signals``        conditioning of measured signals: steps, noise estimates, input conditioning, motor observer
``model``          rig parameters in SI (:class:`RigParameters`) and the catalog of physical effects
``sim``            the rig simulator (:func:`simulate`, :class:`RigSimulator`), excitation, noise injection
``wsindy``         weak SINDy split by role: library, test functions, quadrature, GLS noise model, selection
``identify``       the rig equations with weak SINDy (:func:`identify_pendulum`, :func:`identify_record`)
``diagnosis``      output error, :func:`compare`, :func:`diagnose` and the per-window online analysis
``present``        text, JSON and the HTML report (:func:`write_report`)
``rig``            the hardware side without ROS: frame protocol, sample clock, calibration
``testing``        test doubles for what cannot be here: a pty-backed fake rig device
``cli``            the ``aeropend`` command, one module per verb
=================  ===========================================================================================

The names below are the public API; they are imported on first use, so ``import aeropend_core`` stays cheap
(the numerical modules compile numba kernels). The method and the model are described in ``docs/``; the packages
and the direction of their imports in ``docs/architecture.md``.

Examples
--------
The whole API on one 20 s simulated record, measured as the rig would (40 dB PSNR, 10-bit ADC); run as a doctest
by tests/test_doctests.py (about ten seconds). Simulate it and load it as a recording, also from a CSV file:

>>> import tempfile
>>> from pathlib import Path
>>> import numpy as np
>>> from aeropend_core import (DEFAULT_PARAMETERS, SAMPLE_TIME, MeasurementNoise, Recording, RigParameters,
...                            RigSimulator, from_columns, lhc_schedule, load_recording, simulate)
>>> duty = lhc_schedule(20, seed=4).duty(duration=20)            # duty steps (fraction 0..1) at 490 Hz
>>> run = simulate(duty, noise=MeasurementNoise(psnr_db=40, quantise=True), seed=5)
>>> recording = from_columns(run.columns(with_truth=False), source='simulated')
>>> isinstance(recording, Recording), len(recording), round(len(recording) * SAMPLE_TIME, 3)    # samples, s
(True, 9800, 20.0)
>>> from aeropend_core.io.recording import write_csv
>>> with tempfile.TemporaryDirectory() as folder:
...     write_csv(str(Path(folder) / 'run.csv'), run.columns(with_truth=False))
...     len(load_recording(Path(folder) / 'run.csv'))
9800
>>> isinstance(DEFAULT_PARAMETERS, RigParameters), len(RigSimulator().run(duty[:490]).angle)    # 1 s streamed
(True, 490)

Identify the pendulum's equation with weak SINDy, or any equation with :func:`fit_weak_sindy` (here dx/dt = -2 x):

>>> from aeropend_core import Equation, WeakSindyResult, fit_weak_sindy, identify_pendulum
>>> fit = identify_pendulum(run.time, run.armature_voltage, run.armature_current, run.angle)
>>> {'gravity_stiffness', 'damping', 'thrust_gain'} <= set(fit.parameters)        # SI, with fit.standard_errors
True
>>> from aeropend_core.wsindy import library
>>> time = np.arange(0.0, 5.0, 0.002)                               # s
>>> result = fit_weak_sindy(time, {'x': np.exp(-2 * time)}, [Equation('x', library.polynomial(['x'], degree=1))])
>>> isinstance(result, WeakSindyResult), round(result['x'].coefficients['x'], 2)               # 1/s
(True, -2.0)
>>> result.summary()['dx/dt']['terms'], result.as_text().startswith('dx/dt = (-2'), set(result.to_dict()['dx/dt'])
(['x'], True, {...'coefficients'...})
>>> result.as_html().startswith('<section class="aeropend-weak-sindy">')
True

What ``aeropend identify`` prints, as one call whose result presents itself (its ``as_text()`` and ``to_dict()``
are the verb's text and ``--json``):

>>> from aeropend_core import Identification, identify_record
>>> identification = identify_record(recording, weak_only=True, source='run.csv')
>>> isinstance(identification, Identification), identification.as_text().splitlines()[0]
(True, 'run.csv: 9800 samples (20 s), model pendulum')
>>> identification.to_dict()['estimator'], identification.summary()['verdict'] == identification.verdict
('weak_sindy', True)

Compare the nominal model with the data, diagnose what is missing, write the report:

>>> from aeropend_core import Comparison, Diagnosis, Verdict, compare, diagnose, write_report
>>> comparison = compare(recording)            # fitted on the training part, judged on the held-out part
>>> isinstance(comparison, Comparison), 0 < comparison.fit_percent <= 100    # held-out fit, %
(True, True)
>>> comparison.summary()['model'], comparison.to_dict()['fit_percent'] == comparison.fit_percent
('nominal', True)
>>> 'Parameters (SI, +- 1 sigma):' in comparison.as_text(), comparison.as_html().startswith('<section')
(True, True)
>>> diagnosis = diagnose(recording, drift=False)
>>> isinstance(diagnosis, Diagnosis), diagnosis.verdict in set(Verdict)
(True, True)

The diagnosis presents itself: a short dict, what ``aeropend diagnose`` prints, its ``--json`` object, the report:

>>> diagnosis.summary()['model'], diagnosis.summary()['verdict'] == diagnosis.verdict
('nominal', True)
>>> text = diagnosis.as_text()
>>> text.splitlines()[1], sum(line.startswith('Verdict: ') for line in text.splitlines())
('Model: nominal', 1)
>>> document = diagnosis.to_dict()
>>> document['schema'], list(document).index('plain') == list(document).index('verdict') + 1
('aeropend.diagnosis/1', True)
>>> page = diagnosis.as_html(source='run.csv')
>>> page.startswith('<!DOCTYPE html>'), 'http://' in page
(True, False)
>>> with tempfile.TemporaryDirectory() as folder:
...     write_report(diagnosis, Path(folder) / 'report.html').stat().st_size > 10_000    # bytes
True

An effect of your own, registered for a block only; every mistake is an :class:`AeropendError`:

>>> from aeropend_core import (AeropendError, EffectParameter, InsufficientDataError, StorageError,
...                            UnknownEffectError, catalog_scope, register_effect)
>>> with catalog_scope():
...     stiffness = EffectParameter('cubic_k', '1/s^2', 'cubic spring per inertia', 5.0)
...     @register_effect('cubic_spring', 'a hardening spring', parameters=[stiffness])
...     def cubic_spring(angle, angular_rate, cubic_k):
...         return -cubic_k * angle ** 3
...     bool(np.ptp(simulate(duty[:980], effects={'cubic_spring': 50.0}).angle) > 0)
True
>>> try:
...     simulate(duty[:980], effects={'cubic_spring': 50.0})        # gone with its block
... except UnknownEffectError as error:
...     isinstance(error, AeropendError)
True
>>> all(issubclass(e, AeropendError) for e in (InsufficientDataError, StorageError, UnknownEffectError))
True
"""
from __future__ import annotations

import importlib

from aeropend_core.kernel_cache import check_kernel_cache

# numba checks a cached kernel against its own file only; a change in a module it calls must clear the cache too
check_kernel_cache()

#: public name -> module that defines it
_PUBLIC = {
    'AeropendError': 'aeropend_core.errors',
    'InsufficientDataError': 'aeropend_core.errors',
    'StorageError': 'aeropend_core.errors',
    'UnknownEffectError': 'aeropend_core.errors',
    'Recording': 'aeropend_core.io.recording',
    'from_columns': 'aeropend_core.io.recording',
    'load_recording': 'aeropend_core.io.recording',
    'DEFAULT_PARAMETERS': 'aeropend_core.model.parameters',
    'RigParameters': 'aeropend_core.model.parameters',
    'SAMPLE_TIME': 'aeropend_core.model.parameters',
    'EffectParameter': 'aeropend_core.model.effects',
    'register_effect': 'aeropend_core.model.effects',
    'catalog_scope': 'aeropend_core.model.effects',
    'RigSimulator': 'aeropend_core.sim.simulate',
    'simulate': 'aeropend_core.sim.simulate',
    'lhc_schedule': 'aeropend_core.sim.excitation',
    'MeasurementNoise': 'aeropend_core.sim.noise',
    'Equation': 'aeropend_core.wsindy.weak_form',
    'fit_weak_sindy': 'aeropend_core.wsindy.weak_form',
    'identify_pendulum': 'aeropend_core.identify.pendulum',
    'identify_record': 'aeropend_core.identify.record',
    'Identification': 'aeropend_core.identify.record',
    'WeakSindyResult': 'aeropend_core.wsindy.weak_form',
    'WeakSindyOptions': 'aeropend_core.wsindy.weak_form',
    'Comparison': 'aeropend_core.diagnosis.compare',
    'compare': 'aeropend_core.diagnosis.compare',
    'Diagnosis': 'aeropend_core.diagnosis.diagnose',
    'diagnose': 'aeropend_core.diagnosis.diagnose',
    'Verdict': 'aeropend_core.diagnosis.verdicts',
    'write_report': 'aeropend_core.present.report',
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
