"""Shared test set-up.

- Tests never multicast off the machine (ROS 2 discovery stays on localhost).
- Every test that uses ROS (rclpy, the node modules, the ROS test helpers, ``aeropend run``), itself or through a
  fixture, is marked ``ros`` when collected (by reading its source): ``pytest -m "not ros"`` runs the core alone.
  On a machine without ROS 2 (rclpy not importable) the modules that need it already at import (a top-level ROS
  import or a private ROS domain) are not collected, and the header says which: the fast tier
  ``pytest -m "not slow and not ros"`` then runs there too instead of stopping at collection errors.
- Under pytest-xdist (``pytest.ini``: one worker per core) the ROS and other real-time tests share one group, so
  they run one at a time on one worker while the other workers run the numerical tests (``--dist loadgroup``).
  The group is marked *before* xdist reads the marks (``tryfirst``): xdist's own hook, registered after this file,
  would otherwise run first, see no mark, and spread two graphs over the two workers at once (it did until
  2026-11-28: ``test_real_time_tests_share_one_worker`` now checks it).
- Numerical libraries run one thread per process (``OPENBLAS_NUM_THREADS`` etc., unless already set, so the
  subprocesses the tests start inherit it too): the suite's matrices are small, and on a 2-core machine that runs a
  test process, ROS nodes and CLI subprocesses at once, OpenBLAS's second thread mostly spins. One diagnosis of a
  60 s record took 16.3 s of CPU with the default 2 threads and 10.9 s with 1 (same verdict; load ~15).
- ``clean_record``: one 60 s simulated record of the default rig (Latin-hypercube excitation, 40 dB, 10-bit
  quantisation, seed 7) with its truth, shared by the modules that only read it.
"""
from __future__ import annotations

import importlib.util
import inspect
import os
import re
from pathlib import Path

import pytest

from aeropend_core.blas import single_blas_thread

# One BLAS thread in the test processes, as in the CLI: two test workers with OpenBLAS's two threads each, beside the
# real-time graphs, made a 2 ms product wait half a second for descheduled threads (aeropend_core/blas.py).
_ONE_BLAS_THREAD = single_blas_thread().__enter__()

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
for _threads in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'NUMBA_NUM_THREADS'):
    os.environ.setdefault(_threads, '1')            # before numpy is first imported (test modules import it later)
# the candidates of a diagnosis one after the other: the test workers already fill the cores (the parallel path has
# its own test, tests/test_parallel_fits.py, which sets the number of workers itself)
os.environ.setdefault('AEROPEND_WORKERS', '1')

#: what marks a test (or one of its fixtures) as using ROS: rclpy, the nodes, the ROS test helpers, `aeropend run`
_ROS_USE = re.compile(r'rclpy|aeropend_ros|NodeProcess|private_domain_id|own_context|use_domain|ros2|'
                      r'run_bridge|start_bridge|bridge_process|Listener|[\'"]run[\'"]|ros_env')
#: what marks a test as real time besides ROS: the pty device emulator, the firmware in simavr, `aeropend emulate`
_REAL_TIME = re.compile(r'DeviceEmulator|EmulateProcess|Harness\(|simavr|build_firmware|openpty|[\'"]emulate[\'"]|'
                        r'[\'"]calibrate[\'"]')
#: a module that imports these at its top needs ROS for every test in it
_ROS_MODULE = re.compile(r'^(from|import) (rclpy|sensor_msgs|std_msgs|diagnostic_msgs|rcl_interfaces)\b', re.M)
#: a module that uses ROS already at import: it cannot even be collected without ROS
_ROS_AT_IMPORT = re.compile(_ROS_MODULE.pattern + r'|^\w+ = private_domain_id\(\)', re.M)
_seen: dict[object, bool] = {}


def _ros_available() -> bool:
    """Whether rclpy can be found (without importing it)."""
    try:
        return importlib.util.find_spec('rclpy') is not None
    except (ImportError, ValueError):
        return False


_ROS_AVAILABLE = _ros_available()


def pytest_ignore_collect(collection_path: Path, config):
    if _ROS_AVAILABLE or collection_path.suffix != '.py' or not collection_path.name.startswith('test_'):
        return None
    if _ROS_AT_IMPORT.search(collection_path.read_text(errors='replace')):
        return True
    return None


def pytest_report_header(config):
    if not _ROS_AVAILABLE:
        return ['ROS 2 not importable (no rclpy): the modules that need it at import are not collected']
    return None


def pytest_terminal_summary(terminalreporter):
    # worked out from the files: under pytest-xdist the workers collect, not this process
    if not _ROS_AVAILABLE:
        names = sorted(p.name for p in Path(__file__).parent.glob('test_*.py')
                       if _ROS_AT_IMPORT.search(p.read_text(errors='replace')))
        terminalreporter.write_line(f'not collected without ROS 2: {", ".join(names)}')


def _source_matches(obj, pattern: re.Pattern) -> bool:
    """Whether the source of a function or module matches `pattern` (remembered per object)."""
    key = (obj, pattern.pattern)
    if key not in _seen:
        try:
            _seen[key] = bool(pattern.search(inspect.getsource(obj)))
        except (OSError, TypeError):
            _seen[key] = False
    return _seen[key]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    for item in items:
        function = getattr(item, 'function', None)
        fixtures = getattr(getattr(item, '_fixtureinfo', None), 'name2fixturedefs', {})
        functions = [function] + [d.func for defs in fixtures.values() for d in defs]
        module = getattr(item, 'module', None)
        ros = (module is not None and _source_matches(module, _ROS_MODULE)) or any(
            f is not None and _source_matches(f, _ROS_USE) for f in functions) \
            or item.get_closest_marker('ros') is not None          # marked per case (a docs block that runs a graph)
        if ros:
            item.add_marker(pytest.mark.ros)
        real_time = item.get_closest_marker('real_time') is not None
        if ros or real_time or any(f is not None and _source_matches(f, _REAL_TIME) for f in functions):
            # under pytest-xdist the real-time tests (nodes at 490 Hz, pty devices, simavr) run one at a time on
            # one worker, beside at most one worker of numerical tests: never two graphs competing for the cores
            item.add_marker(pytest.mark.xdist_group('real_time'))


@pytest.fixture(scope='session')
def clean_record():
    """60 s of the default rig under LHC duty steps, 40 dB PSNR, quantised (a ``Trajectory`` with truth)."""
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(60, seed=7).duty(duration=60)
    return simulate(duty, noise=MeasurementNoise(psnr_db=40, quantise=True), seed=7)


@pytest.fixture
def scoped_catalog():
    """The catalog of effects for one test: whatever the test registers (a user's effect, a ``--term``, an effects
    module) leaves it afterwards, so no test's catalog depends on what ran before it in the process
    (:func:`aeropend_core.model.effects.catalog_scope`, as python-control's ``editsdefaults`` fixture)."""
    from aeropend_core.model.effects import catalog_scope
    with catalog_scope() as catalog:
        yield catalog
