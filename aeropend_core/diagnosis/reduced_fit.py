"""The reduced model (no usable armature current): its identification and its re-check in the catalog search.

The motor map (time constant T, curvature q) is profiled by :mod:`aeropend_core.diagnosis.map_profile`; here the
record is prepared and compared on it (:func:`identify_reduced`), its parameters are reported with the map's
(:func:`reduced_parameters`), and the search's effects are re-checked on a map profiled again with them
(:func:`reprofile_and_recheck`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from aeropend_core.diagnosis.candidates import assess
from aeropend_core.diagnosis.compare import Comparison, PreparedRecord, compare, fit_model, prepare
from aeropend_core.diagnosis.map_profile import profile_motor_map
from aeropend_core.errors import InsufficientDataError
from aeropend_core.io.recording import Recording


@dataclass(frozen=True, eq=False)
class ReducedFit:
    """Result of :func:`identify_reduced`: the reduced model's parameters (SI) with their 1σ and its comparison.

    Attributes
    ----------
    parameters : dict of str -> float [SI]
        ``gravity_stiffness`` [1/s^2], ``damping`` [1/s], ``thrust_gain`` [rad/s^2/V^2 of the map],
        ``motor_time_constant`` [s], ``voltage_map_curvature`` [1/V].
    standard_errors : dict of str -> float [SI]
        1σ (the map's are conditional, from the profile; the others are conditional on the map).
    comparison : Comparison
        The output-error fit and its held-out evaluation (fit %, RMS error [rad]).
    prepared : PreparedRecord
        The conditioned record (its ``motor_map``, steps and split).
    """

    parameters: dict[str, float]
    standard_errors: dict[str, float]
    comparison: Comparison = field(repr=False)
    prepared: PreparedRecord | None = field(default=None, repr=False)
    estimator: str = 'output_error'

    def format(self, warnings: dict[str, str] | None = None) -> str:
        """Person-readable lines (units stated; a failing parameter's warning next to it)."""
        from aeropend_core.model.effects import parameter_unit
        from aeropend_core.signals.reduced import MAP_PARAMETERS, NOT_IDENTIFIABLE
        warnings = warnings or {}
        c = self.comparison
        lines = ['reduced model (no period-average armature current): dW/dt = -a sin y - b W + k e|e|, '
                 'T de/dt = Va - e - q e|e|; output-error fit, held-out free-run fit '
                 f'{c.fit_percent:.2f} % (RMS error {c.rms_error * 1e3:.2f} mrad, noise {c.noise_rms * 1e3:.2f} mrad); '
                 '± 1σ conditional on the profiled motor map (docs/reduced-model.md gives the measured bias)']
        for name, value in self.parameters.items():
            unit = MAP_PARAMETERS.get(name) or parameter_unit(name)
            flag = f'   !! {warnings[name]}' if name in warnings else ''
            lines.append(f'  {name} = {value:.6g} ± {self.standard_errors.get(name, float("nan")):.2g} {unit}{flag}')
        lines.append('  not identifiable without the current: ' + '; '.join(f'{k} ({v})'
                                                                            for k, v in NOT_IDENTIFIABLE.items()))
        return '\n'.join(lines)


def reduced_parameters(prep, comparison) -> tuple[dict[str, float], dict[str, float]]:
    """The reduced model's reported parameters and 1σ (no armature resistance; the profiled map added)."""
    values = {k: v for k, v in comparison.parameters.items() if k != 'armature_resistance'}
    errors = {k: v for k, v in comparison.fit.standard_errors.items() if k != 'armature_resistance'}
    motor = prep.motor_map or {}
    for name in ('motor_time_constant', 'voltage_map_curvature'):
        if name in motor:
            values[name] = motor[name]
            errors[name] = motor['standard_errors'][name]
    return values, errors


def identify_reduced(recording, effects=()) -> ReducedFit:
    """Identify the reduced model (module docstring) from a record with the input and the angle only.

    Parameters
    ----------
    recording : Recording
        ``armature_voltage`` [V] (or ``duty``, turned into Va by the gate) and ``angle`` [rad], at least 20 s; an
        ``armature_current`` column is ignored.
    effects : sequence of str [-]
        Catalog effects to include.

    Returns
    -------
    ReducedFit
        Parameters (SI) with 1σ and the held-out comparison.
    """
    signals = {k: v for k, v in recording.signals.items() if k != 'armature_current'}
    prep = prepare(Recording(recording.time, signals, recording.source, tuple(recording.findings)))
    comparison = compare(prep, tuple(effects))
    values, errors = reduced_parameters(prep, comparison)
    return ReducedFit(values, errors, comparison, prep)


def reprofile_and_recheck(prep, model, base, held, search_record):
    """Profile the map again with the effects found, refit, and drop an effect that is no longer significant.

    Parameters
    ----------
    prep : PreparedRecord
        The reduced record (its map profiled on the nominal model).
    model : tuple of str [-]
        Effects the search selected.
    base : Comparison
        The selected model's comparison.
    held : dict of str -> float [SI]
        Parameters held (``--fix``).
    search_record : callable
        :func:`aeropend_core.diagnosis.long_record.search_record`.

    Returns
    -------
    tuple
        ``(prep, search, subset, model, base, notes)``: the record on the new map, the search record and subset, the
        effects kept, their comparison, and one note per effect dropped.
    """
    prep = profile_motor_map(prep, fit_model, model, start=base.parameters, fixed=dict(held))
    search, subset = search_record(prep)
    base = compare(search, model, start=base.parameters, fixed=dict(held))
    notes = []
    for name in tuple(model):
        if name not in model or len(model) < 2:
            continue
        without = tuple(n for n in model if n != name)
        try:
            reduced = compare(search, without, start=base.parameters, fixed=dict(held))
        except InsufficientDataError:
            continue
        if not assess(search, reduced, base, name).significant:
            notes.append(f'{name} was dropped again: on the motor map profiled with the effects found it adds nothing '
                         'significant.')
            model, base = without, reduced
    return prep, search, subset, model, base, notes
