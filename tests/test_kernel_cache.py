"""numba's cache is checked against a kernel's own file only; aeropend_core.kernel_cache clears a module's cached
kernels when a module they are compiled from changes (the closed-loop kernel kept the old control law after
control/law.py gained its setpoint weight, until the cache was deleted by hand)."""
from __future__ import annotations

import os

from aeropend_core.kernel_cache import check_kernel_cache, kernel_dependencies


def _write(path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def _caches(package, stem: str) -> list[str]:
    return sorted(name for name in os.listdir(package / '__pycache__') if name.startswith(stem + '.'))


def _compile(package) -> None:
    """What numba leaves after compiling the kernels of kern.py and solo.py (index and data files)."""
    for stem in ('kern', 'solo'):
        for suffix in ('nbi', '1.nbc'):
            _write(package / '__pycache__' / f'{stem}.step-10.py311.{suffix}', 'machine code')


def test_a_change_in_an_imported_module_clears_only_the_kernels_compiled_from_it(tmp_path):
    package = tmp_path / 'aeropend_core'
    _write(package / '__init__.py', '')
    _write(package / 'law.py', 'GAIN = 1.0\n\ndef law(x):\n    return GAIN * x\n')
    _write(package / 'kern.py', 'import numba\nfrom aeropend_core.law import law\n\n@numba.njit(cache=True)\n'
                                'def step(x):\n    return law(x)\n')
    _write(package / 'solo.py', 'import numba\n\n@numba.njit(cache=True)\ndef step(x):\n    return x\n')
    _write(package / 'words.py', 'TEXT = "a module no kernel uses"\n')
    assert kernel_dependencies(str(package)) == {str(package / 'kern.py'): {str(package / 'kern.py'),
                                                                             str(package / 'law.py')},
                                                 str(package / 'solo.py'): {str(package / 'solo.py')}}
    _compile(package)
    assert check_kernel_cache(str(package))                   # no stamp yet: caches of unknown sources go
    assert _caches(package, 'kern') == [] and _caches(package, 'solo') == []
    _compile(package)
    assert not check_kernel_cache(str(package))               # nothing changed: kept
    assert len(_caches(package, 'kern')) == 2

    _write(package / 'words.py', 'TEXT = "edited"\n')          # no kernel depends on it
    assert not check_kernel_cache(str(package))
    assert len(_caches(package, 'kern')) == 2 and len(_caches(package, 'solo')) == 2

    _write(package / 'law.py', 'GAIN = 0.5\n\ndef law(x):\n    return GAIN * x\n')    # what kern.py's kernel inlines
    assert check_kernel_cache(str(package))
    assert _caches(package, 'kern') == []                     # recompiled on first use
    assert len(_caches(package, 'solo')) == 2                 # compiled from nothing that changed: kept

    os.utime(package / 'law.py')                              # touched, same content (a checkout): kept
    _compile(package)
    assert not check_kernel_cache(str(package)) and len(_caches(package, 'kern')) == 2


def test_the_installed_package_has_a_stamp_after_import():
    import aeropend_core
    check_kernel_cache()
    stamp = os.path.join(os.path.dirname(aeropend_core.__file__), '__pycache__', 'kernel-sources.json')
    assert os.path.isfile(stamp)
    assert 'control/law.py' in open(stamp, encoding='utf-8').read()        # the law the closed-loop kernel inlines
