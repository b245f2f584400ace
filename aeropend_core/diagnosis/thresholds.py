"""The diagnosis's verdict thresholds that modules at every level of it read: a leaf module (no imports).

As mcap's ``well_known.py``: the evidence's words (:mod:`aeropend_core.diagnosis.evidence`), the checks of a
finished diagnosis (:mod:`aeropend_core.diagnosis.checks`) and the search (:mod:`aeropend_core.diagnosis.stages`)
read them here, so none of them imports the one above it. The candidates' evidence thresholds (``T_MIN``,
``BIC_MARGIN``, ``DM_MIN``, ...) are in :mod:`aeropend_core.diagnosis.candidates`.
"""

#: "Unexplained" (the best set leaves error no catalog effect explains) is claimed beyond this multiple of the
#: noise RMS: a smaller excess can come from the noise estimate itself (quantisation that does not dither is partly
#: a slow bias).
UNEXPLAINED_NOISE = 0.5

__all__ = ['UNEXPLAINED_NOISE']
