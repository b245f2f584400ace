"""Argument checks shared by the verbs (not a verb: not listed in VERBS)."""
from __future__ import annotations

from aeropend_core.errors import AeropendError


def check_effect_names(names: list[str], option: str) -> None:
    """Effect names given to --effect/--add/--only must be bare catalog names (their values are fitted)."""
    from aeropend_core.model.effects import CATALOG
    from aeropend_core.errors import UnknownEffectError
    for name in names:
        bare = name.split('=', 1)[0].split('.', 1)[0].strip()
        if '=' in name and bare in CATALOG:
            raise AeropendError(f'{option} {name}: give the effect name only ({option} {bare}); its parameters are '
                                'estimated from the data')
        if name not in CATALOG:
            raise UnknownEffectError(f'unknown effect {name!r} in {option}; known effects: '
                                     f'{", ".join(sorted(CATALOG))} (`aeropend effects` describes them)')


def check_report_path(path: str | None, option: str = '--report') -> None:
    """An HTML report can be written to `path` (a file name in an existing folder): refused before any work."""
    if not path:
        return
    from pathlib import Path
    report = Path(path)
    if report.is_dir() or not report.parent.is_dir():
        raise AeropendError(f'cannot write the report to {report} ({option}): '
                            + ('it is a folder; give a file name such as report.html' if report.is_dir()
                               else f'the folder {report.parent} does not exist'))
