"""The examples in the docstrings run: every ``>>>`` in aeropend_core is a doctest, and every public name of
``aeropend_core`` is used in one (issue #44; python-control runs its examples the same way)."""
from __future__ import annotations

import ast
import doctest
import importlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the package's tour runs a diagnosis (about ten seconds)
SLOW = {'aeropend_core'}


def modules_with_examples() -> list[str]:
    """aeropend_core modules whose source has a ``>>>`` line (found without importing them)."""
    found = []
    for path in sorted((ROOT / 'aeropend_core').rglob('*.py')):
        if re.search(r'^\s*>>> ', path.read_text(encoding='utf-8'), re.M):
            found.append(path.relative_to(ROOT).with_suffix('').as_posix().replace('/', '.').removesuffix('.__init__'))
    return found


def example_lines(module: str) -> str:
    """The ``>>>`` and ``...`` lines of a module's docstrings."""
    path = ROOT / (module.replace('.', '/') + ('/__init__.py' if (ROOT / module.replace('.', '/')).is_dir() else '.py'))
    tree = ast.parse(path.read_text(encoding='utf-8'))
    docs = [ast.get_docstring(node) or '' for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))]
    return '\n'.join(line for doc in docs for line in doc.splitlines() if line.lstrip().startswith(('>>>', '...')))


@pytest.mark.parametrize('module', [pytest.param(m, marks=pytest.mark.slow) if m in SLOW else m
                                    for m in modules_with_examples()])
def test_the_examples_in_the_docstrings_run(module, scoped_catalog):
    finder, out = doctest.DocTestFinder(), io.StringIO()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(importlib.import_module(module)) if t.examples]
    for test in tests:
        runner.run(test, out=out.write)
    result = runner.summarize(verbose=False)
    assert tests, f'{module}: no example found'
    assert result.failed == 0, out.getvalue()


def test_every_public_name_is_used_in_an_example_that_runs():
    import aeropend_core
    examples = '\n'.join(example_lines(m) for m in modules_with_examples())
    missing = [name for name in aeropend_core.__all__ if not re.search(rf'\b{name}\b', examples)]
    assert not missing, f'public names without a doctested example: {missing}'


#: public names whose example is the package's tour (aeropend_core/__init__.py), not their own docstring: values
#: without a docstring of their own, and the calls that need a fitted 20 s record (seconds, not well under one)
IN_THE_TOUR = {'DEFAULT_PARAMETERS', 'SAMPLE_TIME', 'compare', 'Comparison', 'diagnose', 'Diagnosis', 'write_report',
               'identify_pendulum', 'identify_record', 'Identification'}


def test_every_public_name_has_an_example_in_its_own_docstring():
    """A reader of ``help(name)`` sees an example that runs; the few that need a fitted record share the tour's."""
    import inspect

    import aeropend_core
    tour = example_lines('aeropend_core')
    missing = []
    for name in aeropend_core.__all__:
        if name in IN_THE_TOUR:
            if not re.search(rf'\b{name}\b', tour):
                missing.append(f'{name} (not in the package example)')
            continue
        if '>>> ' not in (inspect.getdoc(getattr(aeropend_core, name)) or ''):
            missing.append(name)
    assert not missing, f'public names without a >>> example in their docstring: {missing}'
