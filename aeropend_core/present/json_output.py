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



def json_text(value, indent: int | None = 2) -> str:
    """`value` as JSON text (:func:`finite_json` first, so NaN/inf are null and the text is strict JSON).

    Parameters
    ----------
    value : object [-]
        What to write (see :func:`finite_json`).
    indent : int or None [characters]
        Indentation; None writes one line (JSON lines).
    """
    import json
    return json.dumps(finite_json(value), indent=indent, allow_nan=False, ensure_ascii=False)


def write_json(target: str, value, stream=None) -> None:
    """Write one JSON object to standard output (``target == '-'``) or to the file `target`.

    A file is written to a temporary name next to it and renamed into place, so an interrupted writer leaves
    either the previous file or the complete new one, never half a JSON object.

    Parameters
    ----------
    target : str [-]
        ``'-'`` for standard output, else the file's path.
    value : object [-]
        The object (see :func:`finite_json`).
    stream : file, optional
        Where ``'-'`` writes (default: ``sys.stdout`` at the call).
    """
    import os
    import sys
    text = json_text(value) + '\n'
    if target == '-':
        stream = sys.stdout if stream is None else stream
        stream.write(text)
        stream.flush()
        return
    from aeropend_core.io.atomic import atomic_write
    target = os.path.realpath(target)         # a symbolic link is written through, as the other outputs
    atomic_write(target, lambda handle: handle.write(text))


class JsonLines:
    """JSON lines (one object per line, flushed at once) to standard output (``'-'``) or appended to a file.

    Every line is complete when it is written (one ``write`` of the whole line, then a flush), so a reader, or a
    writer killed between lines, never sees half an object.

    Parameters
    ----------
    target : str [-]
        ``'-'`` for standard output, else the file's path (created, or appended to).
    """

    def __init__(self, target: str) -> None:
        import sys
        self.target = target
        self._handle = sys.stdout if target == '-' else open(target, 'a', encoding='utf-8')

    def write(self, value) -> None:
        """Write `value` (see :func:`finite_json`) as one line [-]."""
        self._handle.write(json_text(value, indent=None) + '\n')
        self._handle.flush()

    def close(self) -> None:
        """Close the file (standard output stays open)."""
        if self.target != '-':
            self._handle.close()


__all__ = ['finite_json', 'json_text', 'write_json', 'JsonLines']
