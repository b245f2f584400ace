"""JSON output of the verbs: plain JSON types, NaN/inf as null (JSON has no NaN), numpy values as numbers."""
from __future__ import annotations

import math

import numpy as np


def finite_json(value):
    """`value` as plain JSON types (dicts, lists, numbers, strings), NaN/inf replaced by null.

    Parameters
    ----------
    value : object [-]
        Nested dicts, lists, tuples, numpy arrays and scalars, numbers and strings.

    Returns
    -------
    object
        The same structure made of JSON types only.
    """
    if isinstance(value, dict):
        return {str(k): finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_json(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


__all__ = ['finite_json']
