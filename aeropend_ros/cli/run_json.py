"""The JSON object of ``aeropend run --json``: one leaf module, so the run and its ``--until-decided`` loop
(:mod:`aeropend_ros.cli.experiment_loop`, which ``run`` imports) write it alike without importing each other."""
from __future__ import annotations

import sys


def write_run_json(target: str, value: dict) -> None:
    """One JSON object (NaN/inf as null) to standard output (``-``) or a file.

    Standard output is the process's own (``sys.__stdout__``), so the JSON reaches it while the run's text is
    redirected to standard error; a file is written atomically and named on standard output (``json: FILE``).

    Parameters
    ----------
    target : str [-]
        ``'-'`` for standard output, else the file's path.
    value : dict [-]
        The object (see :func:`aeropend_core.present.json_output.finite_json`).
    """
    from aeropend_core.present.json_output import write_json
    write_json(target, value, stream=sys.__stdout__)
    if target != '-':
        print(f'json: {target}')
