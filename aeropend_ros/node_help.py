"""``--help`` of the node executables: the node's parameters (default, range, description with its unit) and
topics, read from the node module's source, so that asking for help never starts a node, opens a port or creates a
bag.

Each node declares its parameters with :func:`aeropend_ros._node_util.declare` (name, default, description with the
unit in brackets, range) and its topics with ``create_publisher`` / ``create_subscription``. :func:`node_help`
walks the node module's syntax tree for those calls and evaluates their arguments in the module's namespace (a
default computed from the node's namespace is shown for the root namespace ``/``); nothing of the node is built.
``ros2 run aeropend_ros recorder_node --help`` and ``recorder_node -h`` print it and exit with status 0; arguments
after ``--ros-args`` belong to ROS and are never taken for a request for help.
"""
from __future__ import annotations

import ast
import importlib
import inspect
import textwrap
from dataclasses import dataclass, field

#: what ``-h`` / ``--help`` look like before ``--ros-args``
HELP_FLAGS = ('-h', '--help')


@dataclass
class NodeParameter:
    """One declared parameter as the help shows it.

    Attributes
    ----------
    name : str [-]
    default : object [unit of the parameter]
        The default, or the source text of its expression when it depends on the running node.
    description : str [-]
        The declaration's description (units in brackets).
    allowed : str [-]
        Range or choices ('' when any value of the type).
    read_only : bool [-]
        True when it can only be set at start-up.
    """

    name: str
    default: object
    description: str
    allowed: str = ''
    read_only: bool = False


@dataclass
class NodeTopics:
    """Topics a node publishes and subscribes to: ``(topic, message type)`` pairs [-]."""

    publishes: list[tuple[str, str]] = field(default_factory=list)
    subscribes: list[tuple[str, str]] = field(default_factory=list)
    #: True when some subscriptions are made at run time for topics the parameters choose
    chosen_at_run_time: bool = False


class _RootNamespaceNode:
    """Stands for ``self`` when a default is computed from the node (the root namespace's graph)."""

    def get_namespace(self) -> str:
        return '/'

    def get_name(self) -> str:
        return 'node'


#: functions the help may call while evaluating a default, a description or a topic (pure; nothing starts)
SAFE_CALLS = frozenset({'float', 'int', 'str', 'bool', 'tuple', 'list', 'sorted', 'range', 'getattr', 'escape',
                        'rstrip', 'get_namespace', 'get_name', 'default_include', 'join', 'format'})


def _callee(call: ast.Call) -> str:
    """Name of the called function or method ('' for anything else)."""
    return call.func.id if isinstance(call.func, ast.Name) else \
        call.func.attr if isinstance(call.func, ast.Attribute) else ''


def wants_help(args: list[str] | None) -> bool:
    """True when `args` (``sys.argv[1:]`` when None) ask for help before any ``--ros-args``.

    Parameters
    ----------
    args : list of str or None [-]

    Returns
    -------
    bool
    """
    import sys
    words = list(sys.argv[1:] if args is None else args)
    if '--ros-args' in words:
        words = words[:words.index('--ros-args')]
    return any(word in HELP_FLAGS for word in words)


def read_node(module_name: str) -> tuple[str, list[NodeParameter], NodeTopics]:
    """The docstring, declared parameters and topics of a node module, without building the node.

    Parameters
    ----------
    module_name : str [-]
        e.g. ``'aeropend_ros.recorder_node'``.

    Returns
    -------
    doc : str
    parameters : list of NodeParameter
    topics : NodeTopics
    """
    module = importlib.import_module(module_name)
    tree = ast.parse(inspect.getsource(module))
    names = dict(vars(module))
    parameters: list[NodeParameter] = []
    topics = NodeTopics()

    def value(expression, local):
        unsafe = [call for call in ast.walk(expression) if isinstance(call, ast.Call) and _callee(call) not in
                  SAFE_CALLS]
        if unsafe:           # never run code of the node that could start something (a writer, a port, a server)
            raise ValueError(f'not evaluated: {ast.unparse(unsafe[0])}')
        return eval(compile(ast.Expression(expression), module_name, 'eval'), names, local)  # noqa: S307

    def visit(statements, local):
        for statement in statements:
            if isinstance(statement, ast.For) and isinstance(statement.target, ast.Name):
                try:
                    items = list(value(statement.iter, local))[:100]
                except Exception:  # noqa: BLE001 - a loop over the running node's state: not shown
                    continue
                for item in items:
                    visit(statement.body, {**local, statement.target.id: item})
                continue
            if isinstance(statement, (ast.If, ast.With, ast.Try)):
                visit(getattr(statement, 'body', []), local)
                visit(getattr(statement, 'orelse', []), local)
                continue
            for call in (n for n in ast.walk(statement) if isinstance(n, ast.Call)):
                _record(call, local)
            if isinstance(statement, ast.Assign) and len(statement.targets) == 1 and \
                    isinstance(statement.targets[0], ast.Name):
                try:
                    local[statement.targets[0].id] = value(statement.value, local)
                except Exception:  # noqa: BLE001 - depends on the running node
                    local.pop(statement.targets[0].id, None)

    def _record(call, local):
        callee = _callee(call)
        if callee == 'declare' and len(call.args) >= 4:
            try:
                name = value(call.args[1], local)
                description = value(call.args[3], local)
            except Exception:  # noqa: BLE001
                return
            try:
                default = value(call.args[2], local)
            except Exception:  # noqa: BLE001
                default = ast.unparse(call.args[2])
            flags = {}
            for keyword in call.keywords:
                try:
                    flags[keyword.arg] = value(keyword.value, local)
                except Exception:  # noqa: BLE001
                    pass
            allowed = ''
            if flags.get('choices'):
                allowed = 'one of ' + ', '.join(flags['choices'])
            elif flags.get('low') is not None and flags.get('high') is not None:
                allowed = f'[{flags["low"]:g}, {flags["high"]:g}]'
            if name not in {p.name for p in parameters}:
                parameters.append(NodeParameter(name, default, description, allowed, bool(flags.get('read_only'))))
        elif callee in ('create_publisher', 'create_subscription') and len(call.args) >= 2:
            try:
                topic = value(call.args[1], local)
            except Exception:  # noqa: BLE001 - a topic chosen at run time (recorder, foxglove bridge)
                topics.chosen_at_run_time = topics.chosen_at_run_time or callee == 'create_subscription'
                return
            entry = (str(topic), ast.unparse(call.args[0]))
            target = topics.publishes if callee == 'create_publisher' else topics.subscribes
            if entry not in target:
                target.append(entry)

    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            visit(node.body, {'self': _RootNamespaceNode()})
    return inspect.getdoc(module) or '', parameters, topics


def node_help(executable: str, module_name: str, width: int = 100) -> str:
    """The text ``EXECUTABLE --help`` prints.

    Parameters
    ----------
    executable : str [-]
        e.g. ``'recorder_node'``.
    module_name : str [-]
        The node's module.
    width : int [characters]

    Returns
    -------
    str
    """
    doc, parameters, topics = read_node(module_name)
    lines = [f'usage: {executable} [-h] [--ros-args -p NAME:=VALUE ... | --params-file FILE.yaml ...]',
             f'       ros2 run aeropend_ros {executable} [--ros-args ...]', '']
    lines += [textwrap.fill(paragraph, width) if not paragraph.startswith(' ') else paragraph
              for paragraph in doc.split('\n\n')[:1]]
    lines += ['', 'parameters (ros2 param; -p NAME:=VALUE at start-up; [unit] in the description):']
    for parameter in parameters:
        default = parameter.default
        shown = repr(default) if isinstance(default, str) else str(default)
        extra = ', '.join(part for part in (parameter.allowed, 'start-up only' if parameter.read_only else '') if part)
        lines.append(f'  {parameter.name} (default {shown}{"; " + extra if extra else ""})')
        lines += textwrap.wrap(parameter.description, width - 6, initial_indent='      ', subsequent_indent='      ')
    for title, pairs in (('publishes', topics.publishes), ('subscribes to', topics.subscribes)):
        if pairs:
            lines += ['', f'{title} (relative names resolve in the node\'s namespace):']
            lines += [f'  {topic}  [{kind}]' for topic, kind in pairs]
    if topics.chosen_at_run_time:
        lines += ['', 'subscribes to: the topics its parameters choose (see above), each as soon as a publisher of it '
                  'appears']
    lines += ['', f'Full description: python -m pydoc {module_name}. Ctrl-C stops the node.']
    return '\n'.join(lines)


def print_node_help(executable: str, module_name: str) -> int:
    """Print :func:`node_help` to standard output; return 0 (the exit status).

    Parameters
    ----------
    executable, module_name : str [-]

    Returns
    -------
    int
        0.
    """
    print(node_help(executable, module_name))
    return 0
