"""The public API documents its parameters in one docstring dialect (numpydoc), with units.

For every function and class exported by ``aeropend_core`` (``__all__``), parsed with ``numpydoc.docscrape``:

- the docstring parses as numpydoc without warnings (no unknown sections, no Google-style ``Args:``);
- every parameter of the signature (a class: of its constructor) is documented in ``Parameters``, and nothing else
  is (a stale name fails too); ``*args``/``**kwargs`` are written with their stars or without, either way;
- every documented parameter names its unit in brackets (``[s]``, ``[rad/s]``, ``[V]``, ``[-]`` where the value is
  not a physical quantity) or says ``dimensionless``;
- a function has a ``Returns`` section (a class documents its attributes instead).

Exceptions are exempt from the parameter rules (they take a message), and so are enumerations (``Verdict``:
its members are its documentation). Constants (``DEFAULT_PARAMETERS``,
``SAMPLE_TIME``) are documented where they are defined.
"""
from __future__ import annotations

import enum
import inspect
import re
import warnings

import pytest
from numpydoc import docscrape

import aeropend_core

#: A unit in brackets, e.g. [s], [rad/s^2], [1/(kg m)], [-]; a numeric interval such as [0, 1] is not a unit.
UNIT = re.compile(r'\[-\]|\[(?![\d\s.,+\-−∞e]+\])[^\[\]]+\]')
DIMENSIONLESS = re.compile(r'\bdimensionless\b', re.IGNORECASE)


def public_callables() -> list[str]:
    names = []
    for name in aeropend_core.__all__:
        obj = getattr(aeropend_core, name)
        if (inspect.isclass(obj) or inspect.isfunction(obj)) and not (
                inspect.isclass(obj) and issubclass(obj, (BaseException, enum.Enum))):
            names.append(name)
    return names


def parsed(obj) -> docscrape.NumpyDocString:
    doc = inspect.getdoc(obj) or ''
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        return docscrape.NumpyDocString(doc)


def documented(doc: docscrape.NumpyDocString) -> dict[str, docscrape.Parameter]:
    """Documented parameter name -> its entry; ``a, b : float`` documents both; leading stars are dropped."""
    out = {}
    for entry in doc['Parameters']:
        for name in entry.name.split(','):
            out[name.strip().lstrip('*')] = entry
    return out


def signature_names(obj) -> list[str]:
    parameters = inspect.signature(obj).parameters.values()
    return [p.name for p in parameters if p.name not in ('self', 'cls')]


def test_the_public_api_is_not_empty():
    names = public_callables()
    assert {'simulate', 'RigSimulator', 'fit_weak_sindy', 'diagnose', 'compare', 'write_report'} <= set(names)


@pytest.mark.parametrize('name', public_callables())
def test_docstring_is_numpydoc(name):
    obj = getattr(aeropend_core, name)
    assert inspect.getdoc(obj), f'{name} has no docstring'
    try:
        parsed(obj)
    except Exception as error:  # noqa: BLE001 - numpydoc raises ValueError or warns (made an error here)
        pytest.fail(f'{name}: the docstring is not valid numpydoc: {error}')


@pytest.mark.parametrize('name', public_callables())
def test_every_parameter_is_documented_and_nothing_else(name):
    obj = getattr(aeropend_core, name)
    expected = signature_names(obj)
    have = documented(parsed(obj))
    missing = [n for n in expected if n not in have]
    stale = [n for n in have if n not in expected]
    assert not missing, f'{name}: parameters missing from the Parameters section: {missing}'
    assert not stale, f'{name}: the Parameters section documents names the signature does not have: {stale}'


@pytest.mark.parametrize('name', public_callables())
def test_every_documented_parameter_states_its_unit(name):
    obj = getattr(aeropend_core, name)
    offences = []
    for parameter_name, entry in documented(parsed(obj)).items():
        text = ' '.join([entry.type, *entry.desc])
        if not (UNIT.search(text) or DIMENSIONLESS.search(text)):
            offences.append(parameter_name)
    assert not offences, (f'{name}: give the unit in brackets (e.g. [s], [V], [-] for a non-quantity) or say '
                          f'dimensionless for: {offences}')


@pytest.mark.parametrize('name', [n for n in public_callables() if inspect.isfunction(getattr(aeropend_core, n))])
def test_every_function_documents_what_it_returns(name):
    doc = parsed(getattr(aeropend_core, name))
    assert doc['Returns'] or doc['Yields'], f'{name}: no Returns section'


def test_the_unit_rule_itself():
    """The checker accepts units and rejects bare text and numeric intervals."""
    assert UNIT.search('float [rad/s]') and UNIT.search('sequence of str [-]') and UNIT.search('[1/(kg m)]')
    assert not UNIT.search('float in [0, 1]') and not UNIT.search('a number of seconds')
    assert DIMENSIONLESS.search('float, dimensionless') and not DIMENSIONLESS.search('float')
