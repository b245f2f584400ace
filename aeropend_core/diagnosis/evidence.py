"""Evidence for a discovered term, judged as the catalog's effects are (:class:`TermEvidence`), and its words.

The statistics that stay valid when residuals are correlated (HAC variance and covariance, the Diebold--Mariano
test, the effective number of samples) are in :mod:`aeropend_core.stats`, a leaf module every layer can use.
"""
from __future__ import annotations

import math
from dataclasses import dataclass



def finite_or_none(x: float | None) -> float | None:
    """`x` as a float, or None when it is missing or not finite (JSON has no nan)."""
    return float(x) if x is not None and math.isfinite(x) else None


@dataclass(kw_only=True)
class TermEvidence:
    """The evidence for one discovered term (pendulum or motor equation), as the catalog's effects are judged.

    Attributes
    ----------
    status : str
        ``'proven'``, ``'not_proven'`` (``why_not`` says why), or an equation's own (``'catalog'``, ``'confounded'``).
    weak_coefficient, weak_sigma : float [unit of the term]
        The weak-form screening's coefficient and its sandwich 1-sigma (benchmarks; reported only without doubt);
        nan for a term refitted without being screened (the thrust curve's knee terms beside a catalog set).
    weak_doubt : str
        Why the screening coefficient is given without a +- (:func:`screening_doubt`; '' : its sigma is given).
    value, sigma : float [unit of the term]
        The output-error refit's coefficient and 1-sigma (nan: not refitted).
    excess_before, excess_after : float [unit of the judged signal: rad or A]
        The held-out error beyond the noise without and with the term.
    share_removed : float [-]
        Share of the error beyond the noise (mean square) the term removes.
    t_statistic : float [-]
        |value| / sigma (sigma a sandwich: HAC or by input interval).
    delta_bic : float [-]
        Change of the training BIC (effective sample count) when the term is added.
    dm_statistic : float [-]
        Held-out Diebold--Mariano statistic (positive: the term predicts better).
    why_not : str
        Why it is not proven ('' when it is).
    """

    status: str
    weak_coefficient: float
    weak_sigma: float
    weak_doubt: str = ''
    value: float = math.nan
    sigma: float = math.nan
    excess_before: float = math.nan
    excess_after: float = math.nan
    share_removed: float = math.nan
    t_statistic: float = math.nan
    delta_bic: float = math.nan
    dm_statistic: float = math.nan
    why_not: str = ''

    @property
    def refit_start(self) -> float:
        """The coefficient an output-error refit starts from [unit of the term]: the screening's, 0 when unscreened."""
        return self.weak_coefficient if math.isfinite(self.weak_coefficient) else 0.0

    @property
    def refitted(self) -> bool:
        """True when the output-error refit gave the coefficient (else only the weak form did)."""
        return math.isfinite(self.value)

    def coefficient(self) -> tuple[float, float]:
        """(coefficient, 1-sigma) [unit of the term]: the output-error refit's, or the weak form's when not refitted
        (its sigma nan when ``weak_doubt`` says it has none)."""
        if self.refitted:
            return self.value, self.sigma
        return self.weak_coefficient, (math.nan if self.weak_doubt else self.weak_sigma)

    @property
    def doubt(self) -> str:
        """Why the reported coefficient has no +- ('' when it has one)."""
        return '' if self.refitted else self.weak_doubt

    def evidence_dict(self) -> dict:
        """The JSON keys of the held-out error and the tests, in the order both equations' terms write them."""
        return {'error_beyond_noise_before': finite_or_none(self.excess_before),
                'error_beyond_noise_after': finite_or_none(self.excess_after),
                'share_of_error_removed': finite_or_none(self.share_removed),
                't_statistic': finite_or_none(self.t_statistic), 'delta_bic': finite_or_none(self.delta_bic),
                'dm_statistic': finite_or_none(self.dm_statistic), 'coefficient_doubt': self.doubt}


def screening_doubt(excess: float, noise: float, unit: str, scale: float) -> str:
    """Why a weak-form screening coefficient is given without a +-.

    The screening regresses the discrepancy of a model on the vocabulary's terms and keeps those that stand out: a
    listed coefficient was chosen for its size, so no sigma beside it covers the truth as a +- must (on clean
    records, where every true coefficient is 0, the weak form's sandwich sigma put 4 of 15 listed ones within 2 sigma
    at 490 Hz and 6 of 89 on 22.3 Hz foreign logs: bench/screening_coverage.py). When the screened model also misses
    the data beyond the diagnosis's unexplained line (``UNEXPLAINED_NOISE`` times the noise RMS), every coefficient
    absorbs part of that miss, which is said too. The output-error refit of a term gives its estimate and an honest +-.

    Parameters
    ----------
    excess, noise : float [rad or A]
        The screened model's held-out error beyond the noise, and the noise RMS.
    unit : str
        The unit to show them in (``'mrad'``, ``'mA'``).
    scale : float [-]
        SI to `unit` (1e3).

    Returns
    -------
    str
        One sentence without final full stop.
    """
    from aeropend_core.diagnosis.thresholds import UNEXPLAINED_NOISE
    missed = (f'; the model whose discrepancy was screened misses the data by {excess * scale:.2f} {unit} beyond the '
              f'noise ({noise * scale:.2f} {unit}), and each coefficient absorbs part of that miss'
              if excess > UNEXPLAINED_NOISE * noise else '')
    return ('weak-form screening values have no +-: the terms listed stood out in the screening, so their '
            f'coefficients were chosen for their size and a sigma beside them would not cover the truth{missed}; they '
            'rank the terms, and a refit by output error gives a term\'s estimate')


#: Two explanations' values of one parameter differ when they are further apart than this many combined standard
#: errors sqrt(sa^2 + sb^2) (each +- covers its truth within 2 sigma ~95 % of the time).
DIFFER_SIGMA = 2.0


def differing_parameters(first: dict, first_errors: dict, second: dict, second_errors: dict,
                         limit: float = DIFFER_SIGMA) -> dict[str, tuple[float, float, float, float]]:
    """The parameters two fitted explanations of one record share and disagree on.

    Where a catalog set and a term outside the catalog explain a record alike (confounded), the nominal parameters
    still differ between the two fits (a cable torque of 50 1/s^2 beside gravity halved); a user must know which
    values hang on the choice.

    Parameters
    ----------
    first, first_errors, second, second_errors : dict of str -> float [SI]
        Each fit's parameters and 1-sigma.
    limit : float [-]
        Combined standard errors beyond which two values differ (:data:`DIFFER_SIGMA`).

    Returns
    -------
    dict of str -> (float, float, float, float)
        Per differing parameter: (first value, its sigma, second value, its sigma) [SI], largest separation first.
    """
    rows = []
    for name in first.keys() & second.keys():
        a, b = first[name], second[name]
        sa, sb = first_errors.get(name, math.nan), second_errors.get(name, math.nan)
        if not all(math.isfinite(v) for v in (a, b, sa, sb)):
            continue
        combined = math.hypot(sa, sb)
        if combined > 0 and abs(a - b) > limit * combined:
            rows.append((abs(a - b) / combined, name, (float(a), float(sa), float(b), float(sb))))
    return {name: values for _, name, values in sorted(rows, reverse=True)}


__all__ = ['DIFFER_SIGMA', 'TermEvidence', 'differing_parameters', 'finite_or_none', 'screening_doubt',
           't_statistic_words', 'share_words']


def t_statistic_words(t_statistic: float) -> str:
    """A candidate's parameter test in words: ``'parameter 4.2 HAC standard errors from zero'``, or, for a profiled
    threshold (infinite t: it has no standard error and is not tested against zero), what was done instead."""
    if math.isfinite(t_statistic):
        return f'parameter {t_statistic:.1f} HAC standard errors from zero'
    return 'parameter a threshold placed between two input levels (no standard error; not tested against zero)'


def share_words(share: float, excess_before: float) -> str:
    """The share of the held-out error beyond the noise that a candidate removes, in words; when the model it was
    added to is already within the noise (no error beyond it, ``excess_before`` [rad] <= 0), that instead of a share
    computed from a zero denominator."""
    if not excess_before > 0:
        return ('the model it was added to is already within the noise, so there is no error beyond the noise for '
                'it to remove')
    return f'it removes {share * 100:.0f} % of the held-out mean-square error beyond the noise'
