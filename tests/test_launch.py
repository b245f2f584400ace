"""The launch files (launch/*.launch.py) without ``launch``/``launch_ros`` (no wheels of them on the package index).

Each file is parsed with ``ast`` and checked against the Jazzy launch API it uses: ``generate_launch_description``
returning a ``LaunchDescription`` of ``DeclareLaunchArgument`` and ``launch_ros.actions.Node`` actions; only names
from ``launch``, ``launch.actions``, ``launch.conditions``, ``launch.substitutions``, ``launch_ros.actions``,
``launch_ros.parameter_descriptions`` and ``launch_ros.substitutions``; every ``LaunchConfiguration`` declared.

Then every Node is evaluated the way launch_ros would with the default arguments (a substitution-only parameter value
is YAML-parsed; ``ParameterValue(value_type=...)`` converts) and the real node class is constructed in-process on a
private ROS domain with the shipped YAML file's parameters plus the launch file's: the node's own checks refuse an
undeclared parameter, a wrong type or a value out of range, so a launch file that sets a parameter the node does not
declare fails here. Its executable must be a console script of the package.
"""
from __future__ import annotations

import ast
import importlib
import inspect
import os
from pathlib import Path

import pytest
import yaml

from tests.ros_helpers import ROOT, own_context, private_domain_id

LAUNCH_FILES = sorted((ROOT / 'launch').glob('*.launch.py'))
JAZZY_API = {
    'launch': {'LaunchDescription'},
    'launch.actions': {'DeclareLaunchArgument', 'GroupAction', 'IncludeLaunchDescription'},
    'launch.conditions': {'IfCondition', 'UnlessCondition'},
    'launch.substitutions': {'LaunchConfiguration', 'PathJoinSubstitution', 'TextSubstitution'},
    'launch_ros.actions': {'Node', 'PushROSNamespace'},
    'launch_ros.parameter_descriptions': {'ParameterValue'},
    'launch_ros.substitutions': {'FindPackageShare'},
    'typing': {'List'},
}
PLAIN_MODULES = {'time'}
#: What each graph must let the user choose (issue: effects, port, record folder, namespace).
REQUIRED_ARGUMENTS = {'sim.launch.py': {'namespace', 'effects', 'record', 'model_effects', 'foxglove'},
                      'rig.launch.py': {'namespace', 'port', 'record', 'model_effects', 'foxglove'}}
GRAPHS = {'sim.launch.py': {'sim_node', 'excitation_node', 'identification_node', 'recorder_node', 'foxglove_node'},
          'rig.launch.py': {'serial_bridge_node', 'excitation_node', 'identification_node', 'recorder_node',
                            'foxglove_node'}}


def console_scripts() -> dict[str, str]:
    """executable -> 'module:function' from setup.py's entry_points (read with ast, setup.py is not run)."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == 'entry_points':
            entry_points = ast.literal_eval(node.value)
            return dict(line.replace(' ', '').split('=', 1) for line in entry_points['console_scripts'])
    raise AssertionError('setup.py has no entry_points')


def call_name(node: ast.AST) -> str | None:
    return node.func.id if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) else None


class LaunchFile:
    """The parsed launch file: its imports, launch arguments and Node actions."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.tree = ast.parse(path.read_text(), filename=str(path))
        self.imported: dict[str, str] = {}
        for node in ast.walk(self.tree):
            if isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    self.imported[alias.asname or alias.name] = node.module
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    self.imported[alias.asname or alias.name] = None
        functions = [n for n in self.tree.body if isinstance(n, ast.FunctionDef)]
        assert [f.name for f in functions] == ['generate_launch_description'], path.name
        self.function = functions[0]
        self.variables = {target.id: statement.value for statement in self.function.body
                          if isinstance(statement, ast.Assign) for target in statement.targets
                          if isinstance(target, ast.Name)}
        self.arguments: dict[str, ast.Call] = {}
        self.configurations: set[str] = set()
        self.nodes: list[ast.Call] = []
        for node in ast.walk(self.function):
            name = call_name(node)
            if name == 'DeclareLaunchArgument':
                self.arguments[ast.literal_eval(node.args[0])] = node
            elif name == 'LaunchConfiguration':
                self.configurations.add(ast.literal_eval(node.args[0]))
            elif name == 'Node':
                self.nodes.append(node)

    def default(self, argument: str) -> str:
        keywords = {k.arg: k.value for k in self.arguments[argument].keywords}
        return ast.literal_eval(keywords['default_value'])

    def evaluate(self, node: ast.AST, arguments: dict[str, str]):
        """The value launch would give `node` with these launch arguments (defaults for the others)."""
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            if node.id in self.variables:
                return self.evaluate(self.variables[node.id], arguments)
            raise AssertionError(f'{self.path.name}: unknown name {node.id}')
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            return str(self.evaluate(node.left, arguments)) + str(self.evaluate(node.right, arguments))
        if isinstance(node, ast.Dict):
            return {self.evaluate(k, arguments): v for k, v in zip(node.keys, node.values)}
        name = call_name(node)
        if name == 'LaunchConfiguration':
            key = ast.literal_eval(node.args[0])
            return arguments.get(key, self.default(key))
        if name == 'FindPackageShare':
            assert ast.literal_eval(node.args[0]) == 'aeropend_ros'
            return str(ROOT)                      # the source tree stands in for share/aeropend_ros
        if name == 'PathJoinSubstitution':
            return os.path.join(*[str(self.evaluate(part, arguments)) for part in node.args[0].elts])
        if name == 'ParameterValue':
            text = self.evaluate(node.args[0], arguments)
            value_type = {k.arg: k.value for k in node.keywords}['value_type']
            value = yaml.safe_load(text)
            if isinstance(value_type, ast.Subscript):          # List[str]
                assert isinstance(value, list) and all(isinstance(v, str) for v in value), text
                return value
            return {'float': float, 'int': int, 'str': str, 'bool': bool}[value_type.id](value)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):   # time.strftime(...)
            return 'aeropend_launch'
        raise AssertionError(f'{self.path.name}: cannot evaluate {ast.dump(node)[:120]}')

    def node_parameters(self, node: ast.Call, arguments: dict[str, str]) -> tuple[dict, Path]:
        """(the parameters the launch file sets, the YAML file it loads) for one Node."""
        keywords = {k.arg: k.value for k in node.keywords}
        entries = keywords['parameters'].elts
        yaml_path = Path(self.evaluate(entries[0], arguments))
        values = {}
        for entry in entries[1:]:
            for key, value in self.evaluate(entry, arguments).items():
                scalar = self.evaluate(value, arguments)
                # launch_ros YAML-parses a value that is only substitutions (here: LaunchConfiguration)
                if call_name(value) in ('LaunchConfiguration', 'PathJoinSubstitution') and isinstance(scalar, str):
                    parsed = yaml.safe_load(scalar) if call_name(value) == 'LaunchConfiguration' else scalar
                    scalar = parsed if parsed is not None else scalar
                values[key] = scalar
        return values, yaml_path


@pytest.fixture(scope='module', params=[p.name for p in LAUNCH_FILES])
def launch_file(request) -> LaunchFile:
    return LaunchFile(ROOT / 'launch' / request.param)


def test_launch_files_exist():
    assert {p.name for p in LAUNCH_FILES} == set(GRAPHS)


def test_only_the_jazzy_launch_api(launch_file):
    for name, module in launch_file.imported.items():
        if module is None:
            assert name in PLAIN_MODULES, f'{launch_file.path.name}: import {name}'
        else:
            assert module in JAZZY_API and name in JAZZY_API[module], f'{launch_file.path.name}: {module}.{name}'
    returned = [n.value for n in ast.walk(launch_file.function) if isinstance(n, ast.Return)]
    assert len(returned) == 1 and call_name(returned[0]) == 'LaunchDescription'
    for node in launch_file.nodes:
        keywords = {k.arg for k in node.keywords}
        assert keywords <= {'package', 'executable', 'name', 'namespace', 'parameters', 'output', 'condition',
                            'remappings', 'arguments', 'ros_arguments'}, keywords
        assert {'package', 'executable', 'name', 'namespace', 'parameters'} <= keywords
    for call in (n for n in ast.walk(launch_file.function) if call_name(n) == 'DeclareLaunchArgument'):
        keywords = {k.arg: k.value for k in call.keywords}
        assert isinstance(ast.literal_eval(keywords['default_value']), str)      # launch arguments are text
        assert ast.literal_eval(keywords['description']), 'every argument says what it is'


def test_arguments_declared_used_and_required(launch_file):
    assert launch_file.configurations == set(launch_file.arguments), 'every argument declared and used'
    assert REQUIRED_ARGUMENTS[launch_file.path.name] <= set(launch_file.arguments)


def test_every_node_is_a_console_script_with_its_yaml_and_namespace(launch_file):
    scripts = console_scripts()
    executables = set()
    for node in launch_file.nodes:
        keywords = {k.arg: k.value for k in node.keywords}
        executable = ast.literal_eval(keywords['executable'])
        assert ast.literal_eval(keywords['package']) == 'aeropend_ros'
        assert executable in scripts, f'{executable} is not a console script of setup.py'
        assert ast.literal_eval(keywords['name']) == executable      # the YAML files are keyed by this name
        assert call_name(keywords['namespace']) == 'LaunchConfiguration'
        assert ast.literal_eval(keywords['namespace'].args[0]) == 'namespace'
        values, yaml_path = launch_file.node_parameters(node, {})
        assert yaml_path == ROOT / 'config' / f'{executable}.yaml' and yaml_path.is_file()
        assert f'/**/{executable}' in yaml.safe_load(yaml_path.read_text()), 'YAML applies in any namespace'
        executables.add(executable)
    assert executables == GRAPHS[launch_file.path.name]


def node_class(executable: str):
    module_name, _ = console_scripts()[executable].split(':')
    module = importlib.import_module(module_name)
    from rclpy.node import Node
    classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
               if issubclass(c, Node) and c.__module__ == module.__name__]
    assert len(classes) == 1, classes
    return classes[0]


@pytest.mark.timeout(120)
def test_every_parameter_set_is_declared_by_the_node(launch_file, tmp_path):
    """Construct each node with the YAML file's and the launch file's parameters (default arguments)."""
    from aeropend_ros._ros_env import ensure_ros_environment
    ensure_ros_environment(local_only=True)
    from rclpy.parameter import Parameter

    master, slave = os.openpty()                 # the serial bridge opens its port at start-up
    arguments = {'record': str(tmp_path / 'bags'), 'foxglove_port': '0', 'port': os.ttyname(slave)}
    try:
        with own_context(private_domain_id()) as context:
            for node in launch_file.nodes:
                executable = ast.literal_eval({k.arg: k.value for k in node.keywords}['executable'])
                values, yaml_path = launch_file.node_parameters(node, arguments)
                from_file = yaml.safe_load(yaml_path.read_text())[f'/**/{executable}']['ros__parameters']
                merged = {**from_file, **values}
                overrides = [Parameter(name, value=value) for name, value in merged.items()]
                instance = node_class(executable)(parameter_overrides=overrides, context=context)
                try:
                    declared = set(instance._parameters)
                    assert set(values) <= declared, f'{executable}: {set(values) - declared} not declared'
                    assert set(from_file) <= declared, f'{executable}: {set(from_file) - declared} not declared'
                    for name, value in values.items():
                        assert instance.get_parameter(name).value == value, (executable, name)
                    descriptors = {name: instance.describe_parameter(name) for name in values}
                    assert all(d.description for d in descriptors.values())
                finally:
                    instance.destroy_node()
    finally:
        os.close(master)
        os.close(slave)


def test_setup_installs_the_launch_files_and_layouts():
    text = (ROOT / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in text and "'share/' + package_name + '/launch'" in text
    assert "glob('config/*.json')" in text and "glob('config/*.xml')" in text
