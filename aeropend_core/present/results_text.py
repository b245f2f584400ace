"""Words for the smaller results: a :class:`~aeropend_core.diagnosis.compare.Comparison` and a
:class:`~aeropend_core.wsindy.weak_form.WeakSindyResult` as a short dict, text, an HTML fragment and a JSON-ready dict,
and any result's text as an HTML fragment (:func:`text_html`).

The result classes call these from their ``summary()``/``as_text()``/``as_html()``/``to_dict()`` methods, importing
this module when a method runs; so this module does not import them, not even for annotations: it states the
attributes it reads as structural types (:class:`ComparisonLike`, :class:`WeakSindyLike`, ``typing.Protocol``),
which the result classes meet, and the import graph points one way (docs/architecture.md).
Angles in rad, errors in mrad where the text says so, parameters SI.
"""
from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from typing import Protocol

from aeropend_core.model.effects import find_parameter
from aeropend_core.model.names import NOMINAL_PARAMETERS


class _EvaluationLike(Protocol):
    """What the words read of a held-out evaluation (:class:`~aeropend_core.diagnosis.compare.Evaluation`)."""

    fit_percent: float             #: NRMSE fit [%]
    rms_error: float               #: free-run RMS error [rad]
    noise_rms: float               #: measurement noise RMS [rad]
    prediction_rms: float          #: RMS error of the short-horizon prediction [rad]
    prediction_horizon: float      #: its horizon [s]
    regimes: dict                  #: error by regime (errors [rad], fractions [-])
    worst_windows: list            #: the worst windows (times [s], errors [rad])
    diverged: bool                 #: the fitted model's simulation diverged


class _FitLike(Protocol):
    """What the words read of an output-error fit (:class:`~aeropend_core.diagnosis.output_error.OutputErrorFit`)."""

    parameters: Mapping[str, float]        #: fitted values, SI
    standard_errors: Mapping[str, float]   #: their 1-sigma, SI
    extra: Mapping                         #: further doubts by name (``friction_law_doubt``)
    success: bool                          #: the fit converged
    message: str                           #: the optimiser's message


class ComparisonLike(Protocol):
    """What the words read of a model comparison (:class:`aeropend_core.diagnosis.compare.Comparison` meets it)."""

    effects: tuple[str, ...]       #: the effects added to the nominal model
    evaluation: _EvaluationLike
    fit: _FitLike


class _EquationLike(Protocol):
    """What the words read of one identified equation (:class:`aeropend_core.wsindy.weak_form.EquationFit`)."""

    name: str                              #: its left-hand side
    selected: Sequence[str]                #: the terms kept
    coefficients: Mapping[str, float]      #: (left-hand side unit) / (term unit)
    standard_errors: Mapping[str, float]   #: their 1-sigma, same units
    candidates: Sequence[str]              #: the library
    threshold: float                       #: the sparsity threshold [-]
    residual: float                        #: relative whitened residual [-]
    half_width: int                        #: test functions' half-width [samples]
    power: int                             #: test functions' power [-]
    n_test_functions: int                  #: weak equations used [-]


class WeakSindyLike(Protocol):
    """What the words read of a weak SINDy result (:class:`aeropend_core.wsindy.weak_form.WeakSindyResult` meets
    it)."""

    @property
    def equations(self) -> Sequence[_EquationLike]: ...


def text_html(text: str, title: str, css_class: str) -> str:
    """`text` as a self-contained HTML fragment: a ``<section>`` with a heading and the text preformatted, escaped.

    Parameters
    ----------
    text : str [-]
        What the result prints.
    title : str [-]
        The heading.
    css_class : str [-]
        The section's class (``aeropend-...``), for a page that styles it.
    """
    return (f'<section class="{html.escape(css_class, quote=True)}"><h3>{html.escape(title)}</h3>\n'
            f'<pre>{html.escape(text)}</pre></section>\n')


def _unit(name: str) -> str:
    """The SI unit of a model parameter (nominal or from the catalog; empty when unknown)."""
    if name in NOMINAL_PARAMETERS:
        return NOMINAL_PARAMETERS[name][0]
    found = find_parameter(name)
    return found[1].unit if found else ''


def _excess(rms: float, noise: float) -> float:
    """Error beyond the noise [rad]: sqrt(max(rms^2 - noise^2, 0))."""
    return math.sqrt(max(rms ** 2 - noise ** 2, 0.0))


def _doubts(comparison: ComparisonLike) -> list[str]:
    """What makes the comparison's numbers doubtful, said beside them: a simulation that diverged, a fit that did
    not converge, +- widened by a slow remainder of the residual."""
    doubts = []
    if comparison.evaluation.diverged:
        doubts.append('the fitted model\'s simulation diverges on this input: its parameters are not estimates')
    if not comparison.fit.success:
        doubts.append(f'the output-error fit did not converge ({comparison.fit.message or "no message"}): the '
                      'parameters and their sigmas are doubtful')
    remainder = comparison.fit.extra.get('slow_remainder', {})
    if 'widening' in remainder:
        doubts.append(f'the residual is not only noise: a slow remainder ({remainder["share"]:.0%} of its variance, '
                      f'correlated over {remainder["correlation_time"]:.2g} s) the model does not write; the +- '
                      'count it as correlated noise (widened), but a misfit can also bias the parameters beyond them')
    return doubts


def comparison_summary(comparison: ComparisonLike) -> dict:
    """A comparison on one screen: ``model`` [-], ``fit_percent`` [%], ``rms_error_rad``, ``noise_rms_rad``,
    ``error_beyond_noise_rad`` [rad] and ``doubts`` (list of str: a diverged simulation, a fit that did not
    converge)."""
    evaluation = comparison.evaluation
    return {'model': ' + '.join(('nominal', *comparison.effects)), 'fit_percent': evaluation.fit_percent,
            'rms_error_rad': evaluation.rms_error, 'noise_rms_rad': evaluation.noise_rms,
            'error_beyond_noise_rad': _excess(evaluation.rms_error, evaluation.noise_rms),
            'doubts': _doubts(comparison)}


def comparison_dict(comparison: ComparisonLike) -> dict:
    """A comparison's numbers as plain types (NaN where unknown; :func:`~.json_output.finite_json` makes it JSON).

    Returns
    -------
    dict
        ``model_effects``; ``fit_percent`` [%]; ``rms_error``, ``noise_rms``, ``error_beyond_noise``,
        ``prediction_rms_error`` [rad]; ``prediction_horizon`` [s]; ``parameters`` and ``standard_errors`` (SI,
        1 sigma, HAC) with ``units``; ``regimes`` and ``worst_windows`` (errors [rad], times [s]); ``diverged``,
        ``fit_converged`` and ``doubts``; with dry friction in a diagnosis's model, ``friction_law_doubt`` (the
        part of each ± from the friction law's shape, SI; :mod:`aeropend_core.diagnosis.friction_doubt`); where a
        diagnosis widened the ± by a slow remainder of the residual, ``slow_remainder`` (``share`` [-],
        ``correlation_time`` [s], ``t_statistic`` [-], ``widening``: each sigma over the block-sum one [-];
        :mod:`aeropend_core.diagnosis.remainder_doubt`).
    """
    evaluation, fit = comparison.evaluation, comparison.fit
    shape = {'friction_law_doubt': dict(fit.extra['friction_law_doubt'])} if 'friction_law_doubt' in fit.extra else {}
    remainder = fit.extra.get('slow_remainder', {})
    if 'widening' in remainder:
        shape['slow_remainder'] = {k: remainder[k] for k in ('share', 'correlation_time', 't_statistic', 'widening')}
    return {'model_effects': list(comparison.effects), 'fit_percent': evaluation.fit_percent,
            'fit_definition': 'held-out free-run simulation of the angle, NRMSE fit % as MATLAB compare',
            'rms_error': evaluation.rms_error, 'noise_rms': evaluation.noise_rms,
            'error_beyond_noise': _excess(evaluation.rms_error, evaluation.noise_rms),
            'prediction_rms_error': evaluation.prediction_rms, 'prediction_horizon': evaluation.prediction_horizon,
            'parameters': dict(fit.parameters), 'standard_errors': dict(fit.standard_errors),
            'units': {name: _unit(name) for name in fit.parameters}, 'estimator': 'output_error',
            'regimes': evaluation.regimes, 'worst_windows': evaluation.worst_windows,
            'diverged': bool(evaluation.diverged), 'fit_converged': bool(fit.success), 'doubts': _doubts(comparison),
            **shape}


def comparison_text(comparison: ComparisonLike) -> str:
    """A comparison as text: the model, its held-out fit and errors [mrad], the parameters (SI, +- 1 sigma), the
    error by regime and the doubts (one ``Doubt:`` line each)."""
    evaluation, fit = comparison.evaluation, comparison.fit
    noise = evaluation.noise_rms
    lines = ['Model: ' + ' + '.join(('nominal', *comparison.effects)),
             f'Held-out free-run simulation of the angle: fit {evaluation.fit_percent:.2f} % (NRMSE, MATLAB compare), '
             f'RMS error {evaluation.rms_error * 1e3:.2f} mrad, measurement noise {noise * 1e3:.2f} mrad, error '
             f'beyond noise {_excess(evaluation.rms_error, noise) * 1e3:.2f} mrad',
             f'{evaluation.prediction_horizon:g} s-ahead prediction RMS error '
             f'{evaluation.prediction_rms * 1e3:.2f} mrad',
             'Parameters (SI, +- 1 sigma):']
    for name, value in fit.parameters.items():
        error = fit.standard_errors.get(name, float('nan'))
        lines.append(f'  {name:24s} {value:12.5g} +- {error:9.2g} {_unit(name)}'.rstrip())
    lines.append('Where the model fails (RMS error by regime, mrad; ratio to overall):')
    for name, stats in sorted(evaluation.regimes.items(), key=lambda kv: -kv[1]['ratio_to_overall']):
        lines.append(f'  {stats["rms_error"] * 1e3:7.2f}  x{stats["ratio_to_overall"]:.2f}  {name} '
                     f'({stats["fraction_of_samples"] * 100:.0f} % of samples)')
    lines += [f'Doubt: {doubt}' for doubt in _doubts(comparison)]
    return '\n'.join(lines)


def comparison_html(comparison: ComparisonLike) -> str:
    """A comparison as a self-contained HTML fragment: a ``<section>`` with its summary line and a parameter table
    (SI, +- 1 sigma), its doubts first; no external link, no script."""
    evaluation, fit = comparison.evaluation, comparison.fit
    esc = html.escape
    model = ' + '.join(('nominal', *comparison.effects))
    rows = ''.join(f'<tr><td>{esc(name)}</td><td>{value:.5g}</td><td>{fit.standard_errors.get(name, math.nan):.2g}'
                   f'</td><td>{esc(_unit(name))}</td></tr>' for name, value in fit.parameters.items())
    doubts = ''.join(f'<p class="doubt"><strong>Doubt:</strong> {esc(d)}</p>' for d in _doubts(comparison))
    return (f'<section class="aeropend-comparison"><h3>Model: {esc(model)}</h3>{doubts}'
            f'<p>Held-out free-run fit {evaluation.fit_percent:.2f} % (NRMSE); RMS error '
            f'{evaluation.rms_error * 1e3:.2f} mrad, noise {evaluation.noise_rms * 1e3:.2f} mrad, beyond the noise '
            f'{_excess(evaluation.rms_error, evaluation.noise_rms) * 1e3:.2f} mrad</p>\n'
            '<table><tr><th>parameter</th><th>value</th><th>&plusmn;1&sigma;</th><th>unit</th></tr>'
            f'{rows}</table></section>\n')


def weak_sindy_summary(result: WeakSindyLike) -> dict:
    """A weak SINDy result on one screen: per equation (its left-hand side) the terms kept [-], the relative
    whitened residual [-] and the number of weak equations used [-]."""
    return {eq.name: {'terms': list(eq.selected), 'residual': eq.residual, 'test_functions': eq.n_test_functions}
            for eq in result.equations}


def weak_sindy_dict(result: WeakSindyLike) -> dict:
    """A weak SINDy result's numbers: per equation the coefficients and their 1-sigma standard errors (units
    (left-hand side unit) / (term unit)), the candidates, the threshold, the residual [-] and the test functions'
    half-width [samples] and power [-]."""
    return {eq.name: {'coefficients': dict(eq.coefficients), 'standard_errors': dict(eq.standard_errors),
                      'candidates': list(eq.candidates), 'threshold': eq.threshold, 'residual': eq.residual,
                      'half_width': eq.half_width, 'power': eq.power, 'test_functions': eq.n_test_functions}
            for eq in result.equations}


__all__ = ['text_html', 'comparison_summary', 'comparison_dict', 'comparison_text', 'comparison_html',
           'weak_sindy_summary', 'weak_sindy_dict']
