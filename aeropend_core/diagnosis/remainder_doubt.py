"""The reported +- of a diagnosis widened by a slow remainder in the residual, after every decision (issue 40).

Each output-error fit keeps, beside its block-sum sigma, the variance a significant slow remainder adds
(:mod:`aeropend_core.diagnosis.slow_remainder`, ``fit.extra['slow_remainder']``). The decisions (which effect is
significant, confounded, a look-alike) read the block-sum sigma: they test the model's own hypothesis, and a wider
sigma there would make a confounding test *more* confident (session 23: a term that should have stood in for a
cable torque and an offset fell under its t threshold, and the cable was named alone). The +- the users read -- the
model's parameters and the named effects' -- add that variance at the end of the diagnosis, and a note says so, with
the remainder's share and correlation time and each sigma's growth; the JSON's ``slow_remainder`` carries the same.
"""
from __future__ import annotations

import dataclasses
import math

#: A sigma growing by less than this share is not listed in the note (still widened).
NOTED_GROWTH = 0.05


def widened_comparison(comparison):
    """(`comparison` with each parameter's sigma widened by the fit's slow remainder, {parameter: growth [-]}) --
    unchanged and {} when the fit has no significant slow remainder (or `comparison` is None)."""
    if comparison is None:
        return comparison, {}
    fit = comparison.fit
    remainder = fit.extra.get('slow_remainder') or {}
    extra = remainder.get('extra_variance') or {}
    if not remainder.get('modelled') or not extra or 'widening' in remainder:
        return comparison, dict(remainder.get('widening', {}))
    errors, growth = dict(fit.standard_errors), {}
    for name, variance in extra.items():
        sigma = errors.get(name, math.nan)
        if not (math.isfinite(sigma) and sigma > 0 and math.isfinite(variance) and variance > 0):
            continue
        errors[name] = math.sqrt(sigma ** 2 + variance)
        growth[name] = errors[name] / sigma
    widened = dataclasses.replace(fit, standard_errors=errors,
                                  extra={**fit.extra, 'slow_remainder': {**remainder, 'widening': growth}})
    return dataclasses.replace(comparison, fit=widened), growth


def _widened_found(entry, extra: dict):
    """A selected effect (``Found``) with its parameters' sigma widened by `extra` [SI^2] in quadrature."""
    errors = dict(entry.standard_errors)
    for name, sigma in entry.standard_errors.items():
        variance = extra.get(name, 0.0)
        if math.isfinite(sigma) and sigma > 0 and math.isfinite(variance) and variance > 0:
            errors[name] = math.sqrt(sigma ** 2 + variance)
    return dataclasses.replace(entry, standard_errors=errors)


def _note(comparison, growth: dict) -> str:
    remainder = comparison.fit.extra['slow_remainder']
    grown = sorted(((g, n) for n, g in growth.items() if g > 1.0 + NOTED_GROWTH), reverse=True)
    widens = ('it widens ' + ', '.join(f'{n} x{g:.2f}' for g, n in grown)) if grown else \
        f'no +- grows by more than {NOTED_GROWTH:.0%}'
    model = ' + '.join(comparison.effects) or 'the nominal model'
    return (f'{model}: the residual is not only noise: a slow remainder ({remainder["share"]:.0%} of its variance, '
            f'correlated over {remainder["correlation_time"]:.2g} s, t = {remainder["t_statistic"]:.1f}) that the '
            f'model does not write; the +- of the model\'s parameters and of the named effects count it as '
            f'correlated noise ({widens}; a term the discovery stage proposes keeps its white-noise +-, a lower '
            'bound). Which effects are named or confounded was decided without it (on the model\'s own hypothesis of '
            'white noise beside the effects); such a misfit can also bias the parameters beyond their +-')


def widen_for_slow_remainder(catalog):
    """(`catalog` (``CatalogResult``) with the current and selected models' +- and the selected effects' +-
    widened by their fits' slow remainder, the notes saying so). Call it after every decision."""
    current, growth = widened_comparison(catalog.current)
    notes = [_note(current, growth)] if growth else []
    if catalog.selected is None or catalog.selected is catalog.current:
        selected, selected_growth = (current if catalog.selected is not None else None), growth
    else:
        selected, selected_growth = widened_comparison(catalog.selected)
        if selected_growth:
            notes.append(_note(selected, selected_growth))
    found = catalog.found
    done = catalog.selected is not None and 'widening' in catalog.selected.fit.extra.get('slow_remainder', {})
    if selected is not None and selected_growth and not done:      # widened once only
        extra = selected.fit.extra['slow_remainder'].get('extra_variance', {})
        found = tuple(_widened_found(entry, extra) for entry in catalog.found)
    widened = dataclasses.replace(catalog, current=current, selected=selected,
                                  final=selected if selected is not None else current, found=found)
    return widened, notes


def remainder_dict(comparison) -> dict | None:
    """The JSON of `comparison`'s slow remainder: ``share`` [-], ``correlation_time`` [s], ``t_statistic`` [-],
    ``modelled`` (counted in the +-), ``widening`` {parameter: reported sigma over the block-sum sigma [-]}; None
    when the fit carries none."""
    if comparison is None:
        return None
    remainder = comparison.fit.extra.get('slow_remainder')
    if not remainder:
        return None
    return {'share': remainder.get('share'), 'correlation_time': remainder.get('correlation_time'),
            't_statistic': remainder.get('t_statistic'), 'modelled': bool(remainder.get('modelled')),
            'widening': dict(remainder.get('widening', {}))}


__all__ = ['widen_for_slow_remainder', 'widened_comparison', 'remainder_dict', 'NOTED_GROWTH']
