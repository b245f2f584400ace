"""numba's on-disk kernel cache, cleared when the source behind a kernel changes in any module.

numba checks a cached kernel only against the file that defines it (its modification time and size). A kernel that
calls a compiled function of another module, or reads a constant from one, keeps its old machine code when only that
other module changes: after the controller law (``control/law.py``) gained its setpoint weight, the closed-loop kernel
of ``control/loop.py`` kept running the old law from ``__pycache__`` until the cache files were deleted by hand.
A tree updated in place (``git pull``) would then compute with yesterday's code and say nothing.

:func:`check_kernel_cache` runs once per process when :mod:`aeropend_core` is imported. It costs one ``stat`` of each
source file (about a millisecond) when nothing changed. When a file changed it hashes the *kernel sources*: every
module that uses numba and every ``aeropend_core`` module it imports. The cached kernels (``__pycache__/*.nbi``,
``*.nbc``) of each module whose sources changed are deleted, so numba compiles them again on first use; editing a
module no kernel depends on costs no recompilation. Best effort: a read-only install (no
writable ``__pycache__``) is left alone, as numba itself then keeps no cache there.
"""
from __future__ import annotations

import hashlib
import json
import os
import re

PACKAGE = os.path.dirname(os.path.abspath(__file__))
#: the stamp of the last check: the source files' stat key and the kernel sources' content hash
STAMP_NAME = 'kernel-sources.json'
_USES_NUMBA = re.compile(r'^\s*(?:import numba\b|from numba\b)', re.M)
_IMPORT = re.compile(r'^\s*(?:from\s+aeropend_core\.([\w.]+)\s+import|import\s+aeropend_core\.([\w.]+))', re.M)


def _python_files(package: str) -> list[str]:
    found = []
    for folder, subfolders, names in os.walk(package):
        subfolders[:] = sorted(name for name in subfolders if name != '__pycache__' and not name.startswith('.'))
        found += [os.path.join(folder, name) for name in sorted(names) if name.endswith('.py')]
    return found


def _stat_key(package: str, files: list[str]) -> str:
    digest = hashlib.sha256()
    for path in files:
        status = os.stat(path)
        digest.update(f'{os.path.relpath(path, package)} {status.st_mtime_ns} {status.st_size}\n'.encode())
    return digest.hexdigest()


def _module_file(package: str, dotted: str) -> str | None:
    base = os.path.join(package, *dotted.split('.'))
    for candidate in (base + '.py', os.path.join(base, '__init__.py')):
        if os.path.isfile(candidate):
            return candidate
    return None


def kernel_dependencies(package: str = PACKAGE) -> dict[str, set[str]]:
    """Each module that uses numba (path) -> the sources its kernels may be compiled from (paths): itself, the
    ``aeropend_core`` modules it imports (their constants are frozen into the machine code), and, through each of
    those that uses numba too, that module's own sources (a kernel calling a kernel inlines it)."""
    imports, numba_modules = {}, set()
    for path in _python_files(package):
        text = open(path, encoding='utf-8').read()
        imports[path] = {found for match in _IMPORT.finditer(text)
                         if (found := _module_file(package, match.group(1) or match.group(2))) is not None}
        if _USES_NUMBA.search(text):
            numba_modules.add(path)
    dependencies: dict[str, set[str]] = {}

    def closure(module: str) -> set[str]:
        if module not in dependencies:
            dependencies[module] = {module} | imports[module]          # a cycle's second visit sees this much
            for imported in sorted(imports[module] & numba_modules):
                dependencies[module] |= closure(imported)
        return dependencies[module]
    return {module: closure(module) for module in sorted(numba_modules)}


def _digest(path: str) -> str:
    with open(path, 'rb') as source:
        return hashlib.sha256(source.read()).hexdigest()


def _cached_kernels_of(module: str) -> list[str]:
    """The cache files numba wrote for the kernels of `module` (``__pycache__/<stem>.<kernel>-<line>.pyXY.nb?``)."""
    folder = os.path.join(os.path.dirname(module), '__pycache__')
    stem = os.path.splitext(os.path.basename(module))[0] + '.'
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    return [os.path.join(folder, name) for name in names if name.startswith(stem) and name.endswith(('.nbi', '.nbc'))]


def _read_stamp(path: str) -> dict:
    """The last check's stamp ({} when there is none or it is unreadable)."""
    try:
        with open(path, encoding='utf-8') as file:
            return json.load(file)
    except (OSError, ValueError):
        return {}


def check_kernel_cache(package: str = PACKAGE) -> bool:
    """Delete the package's cached numba kernels when their sources changed since the last check.

    Parameters
    ----------
    package : str [-]
        Folder of the package (this one by default).

    Returns
    -------
    bool
        True when the cached kernels of a module were deleted (its sources, or a module it imports, changed).
    """
    cache = os.path.join(package, '__pycache__')
    stamp_path = os.path.join(cache, STAMP_NAME)
    try:
        stat_key = _stat_key(package, _python_files(package))
        if _read_stamp(stamp_path).get('stat') == stat_key:
            return False
        os.makedirs(cache, exist_ok=True)
        import fcntl
        with open(os.path.join(cache, STAMP_NAME + '.lock'), 'w') as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)        # one process clears; the others then read its stamp
            stamp = _read_stamp(stamp_path)            # another process may have checked meanwhile
            if stamp.get('stat') == stat_key:
                return False
            dependencies = kernel_dependencies(package)
            digests = {os.path.relpath(path, package): _digest(path) for path in set().union(*dependencies.values())}
            before = stamp.get('sources', {})
            changed = {name for name in set(digests) | set(before) if digests.get(name) != before.get(name)}
            stale = [module for module, used in dependencies.items()
                     if {os.path.relpath(path, package) for path in used} & changed]
            for module in stale:
                for path in _cached_kernels_of(module):
                    os.remove(path)
            temporary = f'{stamp_path}.{os.getpid()}'
            with open(temporary, 'w', encoding='utf-8') as file:
                json.dump({'stat': stat_key, 'sources': digests}, file, indent=0, sort_keys=True)
            os.replace(temporary, stamp_path)
            return bool(stale)
    except (OSError, ImportError):
        return False
