"""aeropend_core: the science and I/O of the aeropendulum rig, without ROS.

Folders follow the data flow, from a recording to a verdict:

=================  ===========================================================================================
``io``             recordings in and out: CSV and MCAP bags (:func:`load_recording`, bag writer/reader/recovery)
``signals``        conditioning of measured signals: steps, noise estimates, input conditioning, motor observer
``model``          rig parameters in SI (:class:`RigParameters`) and the catalog of physical effects
``sim``            the rig simulator (:func:`simulate`, :class:`RigSimulator`), excitation, noise injection
``wsindy``         weak SINDy split by role: library, test functions, quadrature, GLS noise model, selection
``identify``       the rig equations from recordings with weak SINDy (:func:`identify_pendulum`)
``diagnosis``      output error, :func:`compare`, :func:`diagnose` and the per-window online analysis
``present``        text, JSON and the HTML report (:func:`write_report`)
``rig``            the hardware side without ROS: frame protocol, sample clock, calibration
``testing``        test doubles for what cannot be here: a pty-backed fake rig device
``cli``            the ``aeropend`` command, one module per verb
=================  ===========================================================================================

The names below are the public API; they are imported on first use, so ``import aeropend_core`` stays cheap
(the numerical modules compile numba kernels). The method and the model are described in ``docs/``.

>>> from aeropend_core import simulate, lhc_schedule, diagnose, from_columns
"""
from __future__ import annotations

import importlib

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
    'RigSimulator': 'aeropend_core.sim.simulate',
    'simulate': 'aeropend_core.sim.simulate',
    'lhc_schedule': 'aeropend_core.sim.excitation',
    'MeasurementNoise': 'aeropend_core.sim.noise',
    'Equation': 'aeropend_core.wsindy.weak_form',
    'fit_weak_sindy': 'aeropend_core.wsindy.weak_form',
    'identify_pendulum': 'aeropend_core.identify.pendulum',
    'compare': 'aeropend_core.diagnosis.compare',
    'diagnose': 'aeropend_core.diagnosis.diagnose',
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
