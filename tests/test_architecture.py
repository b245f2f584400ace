"""Layering of the tree, checked on the source (static, so a lazy or string import counts too).

- ``aeropend_core`` imports no ROS (rclpy, message packages, ``aeropend_ros``) and no pyserial, not even by a
  string handed to importlib; the one exception is the ``calibrate`` verb, which talks to the rig's serial port.
- Library code (``aeropend_core`` outside ``cli``, ``aeropend_ros`` nodes) never imports the command line.
- ``bench/`` and ``tests/`` do not import each other.
- No library module is over 800 lines; every core folder is a package with a docstring.
- Only the result classes import ``present``, inside their presentation methods; ``present`` does not import them,
  not even for annotations (it reads them through ``typing.Protocol`` types: typed results there, words here).
- Imports only point down: no circle in the import graph of ``aeropend_core`` and ``aeropend_ros``, every import
  statement counted (function-level, relative and ``if TYPE_CHECKING:`` ones too).
- Nothing in the repository points at files outside it.
- The second truth simulator (``aeropend_core/testing/second_rig.py``) imports only numpy, scipy and the standard
  library: nothing of the model code it is meant to test (model, sim, signals, diagnosis, ...).
"""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / 'aeropend_core'
ROS_ROOTS = {'rclpy', 'rosidl_runtime_py', 'rosidl_parser', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs',
             'rcl_interfaces', 'builtin_interfaces', 'aeropend_ros'}
#: core files allowed to import pyserial, and why
SERIAL_ALLOWED = {'aeropend_core/cli/calibrate.py': 'the calibrate verb talks to the firmware on the serial port'}
MAX_LINES = 800


def python_files(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob('*.py') if '__pycache__' not in p.parts)


def imported_roots(path: Path) -> dict[str, int]:
    """Top-level modules a file imports (statements anywhere, and string literals naming a module) -> line."""
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    found: dict[str, int] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.setdefault(alias.name.split('.')[0], node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.setdefault(node.module.split('.')[0], node.lineno)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            # 'aeropend_ros.cli.run', 'rclpy', 'sensor_msgs.msg' in importlib calls or tables
            match = re.fullmatch(r'([A-Za-z_]\w*)(\.[A-Za-z_]\w*)*', node.value.strip())
            if match and match.group(1) in ROS_ROOTS | {'serial'}:
                found.setdefault(match.group(1), node.lineno)
    return found


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def test_core_names_no_ros_and_no_serial_even_by_string():
    offences = []
    for path in python_files('aeropend_core'):
        for root, line in imported_roots(path).items():
            if root in ROS_ROOTS or (root == 'serial' and rel(path) not in SERIAL_ALLOWED):
                offences.append(f'{rel(path)}:{line} imports {root}')
    assert not offences, '\n'.join(offences)


def test_core_imports_no_ros_at_run_time():
    code = ('import sys, pkgutil, importlib, aeropend_core\n'
            'for m in pkgutil.walk_packages(aeropend_core.__path__, "aeropend_core."):\n'
            '    importlib.import_module(m.name)\n'
            f'bad = sorted(m for m in sys.modules if m.split(".")[0] in {sorted(ROS_ROOTS | {"serial"})!r})\n'
            'print(bad); sys.exit(1 if bad else 0)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_library_code_never_imports_the_command_line():
    offences = []
    for path in python_files('aeropend_core', 'aeropend_ros'):
        if 'cli' in path.relative_to(ROOT).parts[1:-1]:
            continue
        tree = ast.parse(path.read_text(encoding='utf-8'))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f'{node.module}.{a.name}' for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            if any(re.match(r'aeropend_(core|ros)\.cli(\.|$)', n) for n in names):
                offences.append(f'{rel(path)}:{node.lineno}')
    assert not offences, 'library code imports the CLI:\n' + '\n'.join(offences)


@pytest.mark.parametrize('folder, other', [('bench', 'tests'), ('tests', 'bench')])
def test_bench_and_tests_do_not_import_each_other(folder, other):
    offences = []
    for path in python_files(folder):
        text = path.read_text(encoding='utf-8')
        roots = imported_roots(path)
        if other in roots or re.search(rf"sys\.path\.(insert|append)\(.*['\"]{other}['\"]", text):
            offences.append(rel(path))
    assert not offences, f'{folder} imports {other}: ' + ', '.join(offences)


def test_no_library_module_is_over_800_lines():
    long = {rel(p): n for p in python_files('aeropend_core', 'aeropend_ros')
            if (n := len(p.read_text(encoding='utf-8').splitlines())) > MAX_LINES}
    assert not long, f'split these modules (> {MAX_LINES} lines): {long}'


def test_every_core_folder_is_a_documented_package():
    for folder in sorted(p for p in CORE.iterdir() if p.is_dir() and p.name != '__pycache__'):
        init = folder / '__init__.py'
        assert init.exists(), f'{rel(folder)} has no __init__.py'
        assert ast.get_docstring(ast.parse(init.read_text(encoding='utf-8'))), f'{rel(init)} has no docstring'
    assert (CORE / 'py.typed').exists()


def test_nothing_points_outside_the_repository():
    tracked = subprocess.run(['git', 'ls-files'], cwd=ROOT, capture_output=True, text=True).stdout.split()
    pattern = re.compile(r'NOTES\.md|STYLE\.md|shared/reference|\.\./shared|_DEFAULT_CHOICES')
    offences = []
    for name in tracked:
        path = ROOT / name
        if name == 'tests/test_architecture.py' or name.startswith('bench/results/') or not path.is_file():
            continue
        try:
            text = path.read_text(encoding='utf-8')
        except (UnicodeDecodeError, OSError):
            continue
        offences += [f'{name}:{i}' for i, line in enumerate(text.splitlines(), 1) if pattern.search(line)]
    assert not offences, 'references to files outside the repository:\n' + '\n'.join(offences)


def test_public_api_is_importable_and_listed():
    import aeropend_core
    required = {'load_recording', 'simulate', 'RigSimulator', 'RigParameters', 'DEFAULT_PARAMETERS',
                'identify_pendulum', 'fit_weak_sindy', 'compare', 'diagnose', 'register_effect', 'write_report',
                'AeropendError', 'InsufficientDataError', 'StorageError', 'UnknownEffectError',
                'Diagnosis', 'Comparison', 'WeakSindyResult', 'Verdict', 'catalog_scope'}      # the results too
    assert required <= set(aeropend_core.__all__)
    for name in aeropend_core.__all__:
        assert getattr(aeropend_core, name) is not None
    with pytest.raises(AttributeError):
        aeropend_core.no_such_name  # noqa: B018


def import_graph(*packages: str) -> dict[str, dict[str, int]]:
    """Module -> {module of the same packages it imports: line}, for every ``import`` and ``from ... import`` anywhere
    in the module (function-level, relative and ``if TYPE_CHECKING:`` ones included: an annotation's import is an
    edge a reader follows too).

    ``from package import name`` points at the submodule ``package.name`` when there is one, else at ``package``.
    """
    files = {rel(p)[:-3].replace('/', '.').removesuffix('.__init__'): p for p in python_files(*packages)}
    graph: dict[str, dict[str, int]] = {}
    for name, path in files.items():
        package = name if path.name == '__init__.py' else name.rpartition('.')[0]
        tree = ast.parse(path.read_text(encoding='utf-8'))
        edges = graph.setdefault(name, {})
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = package.split('.')
                    base = '.'.join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
                else:
                    base = node.module or ''
                targets = [f'{base}.{a.name}' if f'{base}.{a.name}' in files else base for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for target in targets:
                if target in files and target != name:
                    edges.setdefault(target, node.lineno)
    return graph


def core_import_graph() -> dict[str, set[str]]:
    """aeropend_core module -> the aeropend_core modules it imports (statements anywhere, lazy ones included)."""
    return {module: set(edges) for module, edges in import_graph('aeropend_core').items()}


def import_circles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module, each as one circle ``a -> b -> ... -> a``."""
    def reachable(start: str) -> dict[str, str]:
        parent, stack = {start: ''}, [start]
        while stack:
            module = stack.pop()
            for nxt in sorted(graph.get(module, ())):
                if nxt not in parent:
                    parent[nxt] = module
                    stack.append(nxt)
        return parent

    reach = {module: reachable(module) for module in graph}
    done: set[str] = set()
    circles = []
    for module in sorted(graph):
        component = {other for other in reach[module] if module in reach[other]}
        if len(component) < 2 or module in done:
            continue
        done |= component
        back = next(m for m in sorted(graph[module]) if m in component)   # module -> back -> ... -> module
        path, parent = [module], reachable(back)
        step = module
        while step != back:
            step = parent[step]
            path.insert(1, step)
        circles.append(sorted(component) + ['circle: ' + ' -> '.join(path + [module])])
    return circles


def test_imports_only_point_down_no_circle():
    """No import circle among the modules of aeropend_core and aeropend_ros, counting every import statement
    (function-level and relative ones too): each module imports only modules below it, so a newcomer reads the tree
    bottom-up. Break a circle by moving the shared constant or function down to a leaf module owned by the lowest
    layer that uses it, by moving a function to where it belongs, or by passing a value in (docs/architecture.md)."""
    graph = import_graph('aeropend_core', 'aeropend_ros')
    circles = import_circles(graph)
    text = []
    for circle in circles:
        members, path = circle[:-1], circle[-1]
        edges = [f'    {a}:{graph[a][b]} imports {b}' for a in members for b in sorted(graph[a]) if b in members]
        text.append(f'{len(members)} modules, {path}\n' + '\n'.join(edges))
    assert not circles, 'import circles (strongly connected components):\n' + '\n'.join(text)


def test_the_import_graph_sees_lazy_relative_and_ros_imports():
    """The circle check above can fail: it sees function-level imports, relative ones and aeropend_ros's, and a
    made-up circle is found and printed."""
    graph = import_graph('aeropend_core', 'aeropend_ros')
    assert 'aeropend_core.stats' in graph['aeropend_core.signals.motor']            # inside fit_motor's helper
    assert 'aeropend_ros.cli.run_json' in graph['aeropend_ros.cli.experiment_loop']     # inside a function
    assert 'aeropend_core.io.samples' in graph['aeropend_core.signals.quality_base']     # the type it annotates with
    assert 'aeropend_core.diagnosis.discovery' in graph['aeropend_core.diagnosis.diagnose']  # under TYPE_CHECKING
    circles = import_circles({'a': {'b': 1}, 'b': {'c': 2}, 'c': {'a': 3}, 'd': {'a': 4}})
    assert circles == [['a', 'b', 'c', 'circle: a -> b -> c -> a']]


#: The result classes that present themselves (``summary()``/``as_text()``/``as_html()``/``to_dict()``), by module:
#: below the verbs, the only modules of the fits and data layers that import present/, and only in their methods.
PRESENTING = {'aeropend_core.diagnosis.diagnose': 'Diagnosis', 'aeropend_core.diagnosis.compare': 'Comparison',
              'aeropend_core.wsindy.weak_form': 'WeakSindyResult', 'aeropend_core.identify.record': 'Identification'}
#: the layers checked by the test below (the others sit above present/ or import only its leaf json_output)
RESULT_LAYERS = ('aeropend_core.diagnosis', 'aeropend_core.identify', 'aeropend_core.wsindy', 'aeropend_core.model',
                 'aeropend_core.sim')


def test_the_results_and_their_wording_import_no_circle():
    """A result presents itself by importing its words from present/ when a method runs (python-control's
    ``TimeResponseData.plot()``), so present/ does not import the result classes, not even for annotations:
    no present module leads back, by any import, to a module that imports present/ (diagnose.py <-> summary.py was
    such a circle)."""
    graph = core_import_graph()

    def reachable(start: str) -> set[str]:
        seen, stack = set(), [start]
        while stack:
            for nxt in graph.get(stack.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        return seen

    circles = []
    for module in sorted(m for m in graph if not m.startswith('aeropend_core.present')):
        for used in sorted(m for m in graph[module] if m.startswith('aeropend_core.present.')):
            if module in reachable(used):
                circles.append(f'{module} -> {used} -> ... -> {module}')
    assert not circles, 'import circles between the results and present/:\n' + '\n'.join(circles)
    assert 'aeropend_core.present.summary' in graph['aeropend_core.diagnosis.diagnose']     # the check sees imports
    assert 'aeropend_core.diagnosis.diagnose' not in graph['aeropend_core.present.summary']  # a Protocol instead


def test_only_the_result_classes_import_present_and_only_in_their_methods():
    """The diagnosis's stages return typed results (``Diagnosis.facts``); the words are made in present/ only
    (``verdict_text.verdict_of``). In the fits and data layers only the modules of the result classes import
    present/, and only inside a function (a method): importing a result loads nothing of present/."""
    graph = import_graph('aeropend_core')
    offences = []
    for module, edges in sorted(graph.items()):
        if not module.startswith(RESULT_LAYERS):
            continue
        used = sorted(m for m in edges if m == 'aeropend_core.present' or m.startswith('aeropend_core.present.'))
        if used and module not in PRESENTING:
            offences.append(f'{module} imports {", ".join(used)} (only {sorted(PRESENTING)} may)')
        elif used:
            path = ROOT / (module.replace('.', '/') + '.py')
            tree = ast.parse(path.read_text(encoding='utf-8'))
            offences += [f'{module}:{node.lineno} imports present/ at module level (import it in the method)'
                         for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))
                         and 'aeropend_core.present' in ast.unparse(node)]
    assert not offences, '\n'.join(offences)
    assert 'aeropend_core.present.verdict_text' in graph['aeropend_core.present.summary']     # the check sees imports


@pytest.mark.real_time
def test_real_time_tests_share_one_worker(request):
    """Under ``--dist loadgroup`` (pytest.ini) the real-time group reaches pytest-xdist: its node ids carry the
    group's name, so no two ROS graphs or pty devices run at once on the two workers (tests/conftest.py)."""
    if not getattr(request.config, 'workerinput', None) or not request.config.getvalue('loadgroup'):
        pytest.skip('not under pytest-xdist with --dist loadgroup: nothing is grouped')
    assert request.node.nodeid.endswith('@real_time'), request.node.nodeid


def test_second_truth_simulator_imports_none_of_the_model_code():
    """A benchmark on the second rig must test the diagnosis against a rig written apart from it (issue 40)."""
    path = CORE / 'testing' / 'second_rig.py'
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    modules = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f'relative import at line {node.lineno}'
            modules.add(node.module)
    roots = {name.split('.')[0] for name in modules}
    allowed = {'numpy', 'scipy', 'math', 'dataclasses', '__future__'}
    assert roots <= allowed, sorted(roots - allowed)
    by_string = [node.value for node in ast.walk(tree) if isinstance(node, ast.Constant)
                 and isinstance(node.value, str) and re.match(r'\s*aeropend_(core|ros)\.', node.value)]
    assert not by_string, by_string
