"""A catalog effect judged against a *modelled* remainder: a disturbance model in prediction-error form (issue #40).

A real rig leaves a remainder the catalog cannot write. Judged against white noise, any effect whose signature
resembles a slow, structured remainder soaks up part of it and looks significant (a thrust loss above a knee read as
an angle offset or a cable torque). Classical system identification (Ljung, *System Identification*, ch. 4 and 7:
Box--Jenkins / innovations form) models the output as ``y = G(q) u + H(q) e`` with a disturbance filter ``H`` and
white innovations ``e``, and scores a model by the innovations' variance, not the output error's.

Here the deterministic part stays the free-run output-error fit (the user-facing score); the disturbance model is
estimated on its residual afterwards, for each model separately (the joint prediction-error likelihood concentrated
over the noise model):

* the free-run residual, stretch by stretch, is averaged over blocks of ``DECIMATED_STEP`` seconds (the measurement
  noise is averaged down; the remainder, slow, is kept);
* an AR(p) filter ``A(q) r = e`` is fitted by least squares on all stretches together, p from 0 to ``MAX_ORDER`` by
  BIC (numpy only);
* the innovations' mean square is the model's score; the evidence for a candidate over its base is the BIC change
  ``n log(s2_candidate / s2_base) + (k_added + p_candidate - p_base) log n`` on the training part (n innovations,
  white by construction), and a Diebold--Mariano statistic on the held-out part's innovations (each model filtered
  by its own training filter), judged as the catalog judges the output error (DM >= 2.33, or >= 1 when it removes
  half of the held-out innovations' mean square).

An effect that holds against its own modelled remainder explains something the remainder's disturbance model cannot
predict from the past residual; a look-alike whose gain lies in what a low-order filter predicts anyway loses it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeropend_core.stats import diebold_mariano

#: Block length [s] over which the free-run residual is averaged before the disturbance model is fitted.
DECIMATED_STEP = 0.05
#: Highest AR order tried (BIC chooses; 0 is white).
MAX_ORDER = 8
#: Stretches shorter than this many decimated samples are not used.
SHORTEST_STRETCH = 3 * MAX_ORDER


@dataclass(frozen=True)
class Disturbance:
    """An AR disturbance model of one model's free-run residual.

    Attributes
    ----------
    coefficients : ndarray, shape (p,) [-]
        ``r_t = sum_i a_i r_{t-i} + e_t``.
    innovation_ms : float [rad^2]
        Mean square of the training innovations.
    count : int [-]
        Training innovations.
    """

    coefficients: np.ndarray
    innovation_ms: float
    count: int

    @property
    def order(self) -> int:
        return int(self.coefficients.size)

    def innovations(self, pieces: list[np.ndarray], start: int = MAX_ORDER) -> np.ndarray:
        """The innovations [rad] of `pieces` (decimated residual stretches) under this filter from sample `start`
        (at least the order) of each stretch on, concatenated."""
        s = max(start, self.order)
        out = [piece[s:] - sum(self.coefficients[i] * piece[s - 1 - i:piece.size - 1 - i] for i in range(self.order))
               for piece in pieces if piece.size > s]
        return np.concatenate(out) if out else np.zeros(0)


def _runs(index: np.ndarray) -> list[np.ndarray]:
    """Runs of `index` at its usual (median) stride (a residual index jumps between segments)."""
    if index.size < 2:
        return [index] if index.size else []
    stride = int(np.median(np.diff(index)))
    breaks = np.flatnonzero(np.diff(index) != stride) + 1
    return np.split(index, breaks)


def decimated_pieces(residual: np.ndarray, index: np.ndarray, sample_time: float) -> list[np.ndarray]:
    """`residual` [rad] at `index`, stretch by stretch, averaged over blocks of ``DECIMATED_STEP`` seconds."""
    pieces = []
    for run in _runs(np.asarray(index)):
        if run.size < 2:
            continue
        step = sample_time * int(run[1] - run[0])
        block = max(int(round(DECIMATED_STEP / step)), 1)
        values = residual[run]
        count = values.size // block
        if count < SHORTEST_STRETCH or not np.all(np.isfinite(values)):
            continue
        pieces.append(values[:count * block].reshape(count, block).mean(axis=1))
    return pieces


def fit_disturbance(pieces: list[np.ndarray]) -> Disturbance | None:
    """The AR(p) disturbance model of `pieces` with p by BIC (None when there is too little data)."""
    pieces = [p for p in pieces if p.size >= SHORTEST_STRETCH]
    if not pieces:
        return None
    best = None
    for order in range(MAX_ORDER + 1):
        # the same samples for every order (the first MAX_ORDER of each stretch are conditioning), so BICs compare
        rows, targets = [], []
        for piece in pieces:
            targets.append(piece[MAX_ORDER:])
            rows.append(np.column_stack([piece[MAX_ORDER - 1 - i:piece.size - 1 - i] for i in range(order)])
                        if order else np.zeros((piece.size - MAX_ORDER, 0)))
        y, x = np.concatenate(targets), np.vstack(rows)
        coefficients = np.linalg.lstsq(x, y, rcond=None)[0] if order else np.zeros(0)
        ms = float(np.mean((y - x @ coefficients) ** 2))
        if not ms > 0:
            ms = 1e-300
        bic = y.size * math.log(ms) + order * math.log(y.size)
        if best is None or bic < best[0]:
            best = (bic, coefficients, ms, y.size)
    return Disturbance(best[1], best[2], best[3])


@dataclass(frozen=True)
class ModelledEvidence:
    """A candidate's evidence against its modelled remainder (module docstring). NaN where not measurable.

    Attributes
    ----------
    delta_bic : float [-]
        Training BIC change of the innovations (negative: the candidate is better).
    dm_statistic : float [-]
        Held-out Diebold--Mariano statistic of the innovations (positive: the candidate predicts better).
    base_order, candidate_order : int [-]
        AR orders of the two disturbance models.
    share_removed : float [-]
        Share of the base model's innovation mean square the candidate removes (training).
    """

    delta_bic: float
    dm_statistic: float
    base_order: int
    candidate_order: int
    share_removed: float
    #: Share of the base model's held-out innovation mean square the candidate removes [-].
    heldout_share: float = math.nan

    def holds(self, bic_margin: float, dm_min: float, dm_weak: float, major_share: float) -> bool:
        """True when the candidate lowers the innovations' BIC by more than `bic_margin` and predicts the held-out
        innovations better: DM at least `dm_min`, or at least `dm_weak` when it removes at least `major_share` of
        their mean square (the catalog's held-out rule, on the innovations: a short held-out part holds few
        independent pieces of evidence)."""
        predictive = self.dm_statistic >= dm_min or (self.dm_statistic >= dm_weak
                                                     and self.heldout_share >= major_share)
        return bool(self.delta_bic < -bic_margin and predictive)

    def sentence(self) -> str:
        return (f'against a modelled remainder (AR({self.candidate_order}) disturbance of {DECIMATED_STEP * 1e3:.0f} '
                f'ms blocks; the base model\'s AR({self.base_order})): innovations BIC {self.delta_bic:+.1f}, '
                f'held-out Diebold-Mariano {self.dm_statistic:+.1f}, '
                f'{self.share_removed * 100:.0f} % of the innovation variance removed (held out: '
                f'{self.heldout_share * 100:.0f} %)')


def modelled_evidence(prep, base, augmented, added: int) -> ModelledEvidence | None:
    """The evidence that `augmented` (`base` plus `added` parameters) explains more than `base` once each one's
    remainder is modelled by its own AR disturbance (None when there is too little data for it)."""
    train, held = np.asarray(prep.train.residual_index), np.asarray(prep.heldout.residual_index)
    models, held_innovations = [], []
    for comparison in (base, augmented):
        residual = prep.angle - comparison.evaluation.simulated
        disturbance = fit_disturbance(decimated_pieces(residual, train, prep.sample_time))
        if disturbance is None:
            return None
        models.append(disturbance)
        held_innovations.append(disturbance.innovations(decimated_pieces(residual, held, prep.sample_time)))
    (b, c), (eb, ec) = models, held_innovations
    n = min(b.count, c.count)
    delta_bic = float(n * math.log(max(c.innovation_ms, 1e-300) / max(b.innovation_ms, 1e-300))
                      + (added + c.order - b.order) * math.log(n))
    # (a simulation that runs away on the held-out part leaves no finite stretch: no held-out evidence)
    dm, _ = diebold_mariano(eb, ec) if eb.size and eb.size == ec.size else (math.nan, math.nan)
    share = float(1.0 - c.innovation_ms / b.innovation_ms) if b.innovation_ms > 0 else math.nan
    held_ms = float(np.mean(eb ** 2)) if math.isfinite(dm) else 0.0
    held_share = float(1.0 - np.mean(ec ** 2) / held_ms) if held_ms > 0 else math.nan
    return ModelledEvidence(delta_bic, float(dm), b.order, c.order, share, held_share)


__all__ = ['DECIMATED_STEP', 'Disturbance', 'ModelledEvidence', 'decimated_pieces', 'fit_disturbance',
           'modelled_evidence']
