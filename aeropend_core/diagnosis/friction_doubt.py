"""The ± of a model with dry friction, widened by how much its parameters depend on the friction law's shape.

The catalog writes dry friction as Fc tanh(W / w0) with a fixed smoothing rate w0 (``FRICTION_SMOOTHING``,
10 mrad/s). A real bearing's friction has a shape of its own (a sharper or softer sign, Stribeck, stiction), and
the fitted parameters move with the shape assumed: on the second truth simulator, whose friction changes sign over
~5 mrad/s, Fc came out 3-7 % high with a ± of 0.5-1 % (z +3 to +10) and damping was pulled low beside it
(bench/results/2026-12-07-s19-second-rig). The ± of the noise alone does not hold a law of another shape.

So where the model has dry friction, the fit is repeated twice from its own values with the sign smoothed over
w0 / FACTOR and w0 x FACTOR (the range of shapes taken as plausible; the RK4 step's stability floor still applies,
``output_error.FRICTION_STABILITY``). Every parameter's largest move over the two refits is its *friction-law
doubt*; its ± becomes the noise's and that doubt in quadrature, and a note says so beside the number (text, JSON,
report, as :mod:`aeropend_core.diagnosis.model_doubt` does for a remainder's terms). The refits' parameters are not
reported: the catalog's law stays the one the values are given for.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from aeropend_core.diagnosis.compare import Comparison, PreparedRecord
from aeropend_core.diagnosis.output_error import FRICTION_STABILITY, STRIDE, OutputErrorFit, fit_output_error
from aeropend_core.parallel import map_in_order, workers_for
from aeropend_core.model.effects import FRICTION_SMOOTHING, kernel_parameter

#: The smoothing rate is varied by this factor both ways (w0 / 2 and 2 w0): 5 and 20 mrad/s around the catalog's 10.
FACTOR = 2.0
#: Most residual evaluations of each refit (they start from the fit, so they need few).
REFIT_ITERATIONS = 30
#: A parameter is named in the note when its ± grows by more than this share.
NOTED_GROWTH = 0.1


def friction_shape_shifts(prep: PreparedRecord, fit: OutputErrorFit
                          ) -> tuple[dict[str, float], tuple[float, ...], tuple[float, ...]]:
    """(largest move of each fitted parameter over the refits with the friction law's shape varied [SI],
    the smoothing rates used [rad/s], each refit's relative change of the training residual RMS [-]);
    ``({}, (), ())`` when the model has no dry friction.

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record the fit was made on (its training segments).
    fit : OutputErrorFit [-]
        The output-error fit (parameters SI); held parameters (no σ) and a thrust gate's threshold stay held.
    """
    structure = fit.structure
    friction = kernel_parameter(structure.effects, 'rate_sign')
    if friction is None or not math.isfinite(fit.parameters.get(friction, math.nan)):
        return {}, (), ()
    held = {name: value for name, value in fit.parameters.items()
            if name not in fit.free_names or name == structure.gate_parameter}
    step = STRIDE * prep.train.sample_time
    moves: dict[str, float] = {}
    rates, changes = [], []
    smoothings = (structure.friction_smoothing / FACTOR, structure.friction_smoothing * FACTOR)

    def refit_with(rate: float) -> OutputErrorFit:
        return fit_output_error(prep.train, replace(structure, friction_smoothing=rate), dict(fit.parameters),
                                fixed=held, max_iterations=REFIT_ITERATIONS, initial_states=fit.initial_states,
                                covariance=False)      # the cost and the parameters are read, no sigma
    # the two refits are independent: side by side on the cores (the same numbers)
    for rate, refit in zip(smoothings, map_in_order(refit_with, smoothings, workers_for(len(prep.angle)))):
        # the width the kernel actually uses (its stability floor, Fc h / FRICTION_STABILITY)
        rates.append(max(rate, abs(fit.parameters[friction]) * step / FRICTION_STABILITY))
        changes.append(refit.residual_rms / fit.residual_rms - 1.0)
        for name in fit.free_names:
            if name in held:
                continue
            move = abs(refit.parameters[name] - fit.parameters[name])
            if math.isfinite(move):
                moves[name] = max(moves.get(name, 0.0), move)
    return moves, tuple(rates), tuple(changes)


def widen_for_friction_shape(prep: PreparedRecord, comparison: Comparison | None
                             ) -> tuple[Comparison | None, list[str]]:
    """(`comparison` with every parameter's ± widened by its friction-law doubt, a note) -- unchanged and no note
    when the model has no dry friction or `comparison` is None.

    The fit's ``extra['friction_law_doubt']`` holds the doubt of each parameter [SI] and
    ``extra['friction_law_smoothing']`` the smoothing rates the refits used [rad/s] and
    ``extra['friction_law_rms_change']`` each refit's relative change of the training residual RMS [-] (negative:
    the record fits that shape better than the catalog's).
    """
    if comparison is None:
        return comparison, []
    fit = comparison.fit
    moves, rates, changes = friction_shape_shifts(prep, fit)
    if not moves:
        return comparison, []
    errors = dict(fit.standard_errors)
    grown = []
    for name, move in moves.items():
        sigma = errors.get(name, math.nan)
        if not math.isfinite(sigma):
            continue
        errors[name] = math.hypot(sigma, move)
        if errors[name] > (1.0 + NOTED_GROWTH) * sigma:
            grown.append(f'{name} {move:.3g} (beside the noise\'s {sigma:.2g})')
    widened = replace(fit, standard_errors=errors,
                      extra={**fit.extra, 'friction_law_doubt': dict(moves), 'friction_law_smoothing': list(rates),
                             'friction_law_rms_change': list(changes)})
    model = ' + '.join(comparison.effects)
    widens = ('it widens ' + ', '.join(grown)) if grown else f'no +- grows by more than {NOTED_GROWTH:.0%}'
    note = (f'{model}: the +- include the doubt of the dry-friction law\'s shape: refitted with its sign smoothed '
            f'over {rates[0] * 1e3:.3g} and {rates[1] * 1e3:.3g} mrad/s instead of {FRICTION_SMOOTHING * 1e3:.3g} '
            f'(a real bearing\'s friction has a shape of its own; the training error changes by '
            f'{changes[0]:+.1%} and {changes[1]:+.1%}), every parameter\'s largest move is added in quadrature; '
            + widens)
    return replace(comparison, fit=widened), [note]


def widen_found(found: list, comparison: Comparison | None) -> list:
    """The selected effects' ± (``Found``) taken from the widened `comparison`, their friction-law doubt added to
    ``model_doubt`` [SI]."""
    if comparison is None or 'friction_law_doubt' not in comparison.fit.extra:
        return list(found)
    doubt, errors = comparison.fit.extra['friction_law_doubt'], comparison.fit.standard_errors
    out = []
    for entry in found:
        names = [n for n in entry.standard_errors if n in doubt and np.isfinite(errors.get(n, math.nan))]
        if not names:
            out.append(entry)
            continue
        out.append(replace(entry, standard_errors={**entry.standard_errors, **{n: errors[n] for n in names}},
                           model_doubt={**entry.model_doubt, **{n: doubt[n] for n in names}}))
    return out


__all__ = ['friction_shape_shifts', 'widen_for_friction_shape', 'widen_found', 'FACTOR']
