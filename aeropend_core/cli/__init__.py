"""The `aeropend` command: one module per verb, each with ``add_arguments(parser)`` and ``main(args) -> int``.

Verbs are imported lazily, so `aeropend simulate` never imports ROS. The core's own verbs are listed in
:data:`VERBS`; other packages add theirs through the ``aeropend.verbs`` entry-point group (``name =
package.module``, the module's first docstring line is the help), which is how the ROS verbs of `aeropend_ros`
(``run``, ``monitor``) arrive without the core naming them.

Exit statuses and what reaches standard error:

- 0 done; 2 a user mistake (:class:`aeropend_core.errors.AeropendError`, or a command-line syntax error from
  argparse): one line ``aeropend VERB: error: <what is wrong and what to do>``;
- 1 the system refused to store or read data (:class:`aeropend_core.errors.StorageError`: disk full, file size
  limit, permissions; or an ``OSError`` nobody turned into a clear message): one line naming the file and the
  operating system's reason;
- the rule for files: **the operating system refusing is 1, a wrong path is 2**, reading and writing alike. 1 for
  permission denied (EACCES, EPERM), a read-only file system, a full disk or quota, the file size limit and I/O
  errors (:data:`aeropend_core.io.paths.SYSTEM_REFUSALS`, :func:`aeropend_core.io.paths.storage_error`); 2 for a
  path that is missing, a folder where a file is expected, a device, FIFO or socket as an output, a symbolic link
  loop, or a file whose content is not a recording;
- 1 an internal error (any other exception, i.e. a bug in aeropend, not in the input): one line naming the
  exception, and how to get the traceback (``AEROPEND_DEBUG=1``) to report it. With ``AEROPEND_DEBUG=1`` every
  exception propagates with its full traceback;
- 130 interrupted (Ctrl-C); 141 the reader of standard output went away (``aeropend simulate | head``).

Warnings (e.g. a bag cut short by a killed recorder, duplicated samples dropped) print as one line
``aeropend VERB: warning: ...``.
"""
from __future__ import annotations

import argparse
import functools
import importlib
import importlib.util
import os
import sys
import warnings

from aeropend_core.errors import AeropendError

#: verb -> (module implementing it, one-line help)
VERBS: dict[str, tuple[str, str]] = {
    'simulate': ('aeropend_core.cli.simulate', 'simulate the rig under a Latin-hypercube excitation, write CSV'),
    'identify': ('aeropend_core.cli.identify', 'identify the rig equations with weak SINDy from CSV or MCAP'),
    'diagnose': ('aeropend_core.cli.diagnose', 'compare model and data, find the missing physical effect'),
    'effects': ('aeropend_core.cli.effects', 'list the catalog of physical effects'),
    'bag-recover': ('aeropend_core.cli.bag_recover', 'repair a bag whose recorder was killed'),
    'calibrate': ('aeropend_core.cli.calibrate', 'measure sensor zeros, angle scale, Ra and Kw on the rig (serial)'),
    'emulate': ('aeropend_core.cli.emulate', 'start the fake rig (device emulator) on a pty and print its port'),
    'import': ('aeropend_core.cli.import_log', 'import a log written by another rig through a log profile, write CSV'),
    'control': ('aeropend_core.cli.control', 'design a controller on a model, check a closed-loop record, linearise'),
}


#: entry-point group through which other packages add verbs
VERB_GROUP = 'aeropend.verbs'


def all_verbs() -> dict[str, tuple[str, str]]:
    """The core's verbs and those registered in the ``aeropend.verbs`` entry-point group (verb -> module, help)."""
    verbs = dict(VERBS)
    for point in sorted(_verb_entry_points(), key=lambda p: p.name):
        verbs.setdefault(point.name, (point.value, _plugin_help(point.value)))
    return verbs


@functools.cache
def _verb_entry_points() -> tuple:
    """The ``aeropend.verbs`` entry points of the installed distributions.

    ``importlib.metadata.entry_points(group=...)`` builds every distribution's metadata (about 0.3-0.5 s with a ROS
    install's hundreds of packages) before selecting the group; this reads the ``entry_points.txt`` files directly
    and builds only the distributions that name the group (a few ms), with the same rule: a distribution found
    again later on ``sys.path`` is a shadowed copy and is skipped.
    """
    from importlib.metadata import PathDistribution
    from pathlib import Path
    points, seen = [], set()
    for folder in sys.path:
        try:
            entries = sorted(os.scandir(folder or '.'), key=lambda entry: entry.name)
        except OSError:
            continue
        for entry in entries:
            if not entry.name.endswith(('.dist-info', '.egg-info')):
                continue
            name = entry.name.rsplit('.', 1)[0].split('-', 1)[0].lower().replace('-', '_').replace('.', '_')
            if name in seen:
                continue
            seen.add(name)
            try:
                with open(os.path.join(entry.path, 'entry_points.txt'), encoding='utf-8') as file:
                    if f'[{VERB_GROUP}]' not in file.read():
                        continue
            except OSError:
                continue
            points.extend(PathDistribution(Path(entry.path)).entry_points.select(group=VERB_GROUP))
    return tuple(points)


def _plugin_help(module_name: str) -> str:
    """First line of a plugin verb module's docstring, read without importing it (its imports may be heavy)."""
    spec = importlib.util.find_spec(module_name)
    if spec is None or not spec.origin:
        return ''
    import ast
    try:
        doc = ast.get_docstring(ast.parse(open(spec.origin, encoding='utf-8').read())) or ''
    except (OSError, SyntaxError):
        return ''
    first = doc.strip().splitlines()[0].rstrip('.') if doc.strip() else ''
    return first[:1].lower() + first[1:]          # as the core verbs' help: lower case, no full stop


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The verbs' help: the module docstring as written (its examples keep their lines) and every option's default
    shown after its help (``(default: 60.0)``), unless the help already names it or there is none to show."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ''
        if 'default' in help_text.lower() or action.default in (None, False, [], argparse.SUPPRESS) or \
                action.option_strings == [] and action.nargs is None:
            return help_text
        return help_text + ' (default: %(default)s)'


class VerbParser(argparse.ArgumentParser):
    """An argument parser that never guesses and answers a mistake with its own verb's usage and one error line.

    ``allow_abbrev=False`` (``--ad`` is not ``--add``, ``--effect`` not ``--effects-module``); an unknown option is
    answered ``aeropend VERB: error: unrecognized option --efect (did you mean --effect?)`` with exit status 2, and
    the verb's usage above it, not the top-level one.
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs['allow_abbrev'] = False
        kwargs.setdefault('formatter_class', HelpFormatter)
        super().__init__(*args, **kwargs)

    def parse_args(self, args=None, namespace=None):
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(unrecognized_message(self, extras))
        return parsed

    def error(self, message: str):
        """Print this parser's usage and ``PROG: error: MESSAGE`` on standard error; exit with status 2."""
        self.print_usage(sys.stderr)
        self.exit(2, f'{self.prog}: error: {message}; see {self.prog} --help\n')


#: options people reach for by another verb's name or an old one -> the option that means that here
SYNONYMS = {'--effect': '--add', '--model-effect': '--add', '--effects': '--add', '--add-effect': '--add',
            '--quite': '--quiet', '--html': '--report'}


_QUANTISED = ('the simulator of `aeropend run` always quantises the angle and the current like the rig\'s 10-bit ADC '
              '(sim_node parameter quantise); --quantise is an option of `aeropend simulate`')
#: (verb, option of another verb) -> what it means here: said instead of a guess at a look-alike option
#: (`run --quantise` was answered "did you mean --quiet?")
OTHER_VERBS_OPTIONS = {
    ('run', '--quantise'): _QUANTISED, ('run', '--quantize'): _QUANTISED,
    ('run', '--no-truth'): '`aeropend run` records no truth columns; --no-truth is an option of `aeropend simulate`',
}


def unrecognized_message(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """'unrecognized option --efect (did you mean --effect?)' for the first unknown option in `extras` (or the
    unexpected arguments when no option is among them)."""
    import difflib
    known = sorted({option for action in parser._actions for option in action.option_strings
                    if action.help != argparse.SUPPRESS})
    for extra in extras:
        if not extra.startswith('-') or extra == '-':
            continue
        name = extra.split('=', 1)[0]
        if name in known:                 # a known option after an unknown one: keep looking
            continue
        meaning = OTHER_VERBS_OPTIONS.get((parser.prog.removeprefix('aeropend '), name))
        if meaning is not None:
            return f'unrecognized option {name} ({meaning})'
        typo = difflib.get_close_matches(name, known, n=1, cutoff=0.85)        # --efect, --quantize, --durration
        synonym = difflib.get_close_matches(name, list(SYNONYMS), n=1, cutoff=0.85)   # another verb's word
        suggestion = typo[0] if typo else SYNONYMS[synonym[0]] if synonym and SYNONYMS[synonym[0]] in known else None
        if suggestion is None:
            prefixed = [option for option in known if option.startswith(name) and len(name) > 2]
            close = prefixed if len(prefixed) == 1 else difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            suggestion = close[0] if close else None
        hint = f' (did you mean {suggestion}?)' if suggestion else ''
        return f'unrecognized option {name}{hint}'
    return f'unrecognized arguments: {" ".join(extras)}'


def version() -> str:
    """'aeropend 0.1.0' from the installed package's metadata (the source tree's setup.py when not installed)."""
    from importlib.metadata import PackageNotFoundError, packages_distributions
    from importlib.metadata import version as installed_version
    try:            # the distribution that installs this package (named by the metadata, not here)
        return f'aeropend {installed_version(packages_distributions()["aeropend_core"][0])}'
    except (PackageNotFoundError, KeyError, IndexError):
        import re
        setup = os.path.join(os.path.dirname(__file__), '..', '..', 'setup.py')
        try:
            found = re.search(r"version='([^']+)'", open(setup, encoding='utf-8').read())
        except OSError:
            found = None
        return f'aeropend {found.group(1) if found else "(version unknown)"}'


class _VersionAction(argparse.Action):
    """``--version``: prints :func:`version` and exits 0; the metadata is read only when asked (it costs ~1 s)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version())
        parser.exit()


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser; only the verb named first in `argv` has its module imported."""
    parser = VerbParser(
        prog='aeropend', formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Aeropendulum rig: record, identify (weak SINDy) and diagnose missing physics.',
        epilog='`aeropend VERB --help` describes a verb. Exit status: 0 done, 2 a mistake in the command or the '
               'input (one line says what to do), 1 the system refused or a bug.')
    parser.add_argument('--version', action=_VersionAction)
    sub = parser.add_subparsers(dest='verb', metavar='VERB', parser_class=VerbParser)
    for verb, (module_name, help_text) in all_verbs().items():
        if verb in argv[:1]:
            verb_parser(verb, sub=sub, help_text=help_text, module_name=module_name)
        else:
            sub.add_parser(verb, help=help_text)
    return parser


def verb_parser(verb: str, sub=None, help_text: str | None = None, module_name: str | None = None) -> VerbParser:
    """The parser of one verb (``prog`` 'aeropend VERB'), its module imported; added to `sub` when given."""
    if module_name is None:
        module_name, help_text = all_verbs()[verb]
    module = importlib.import_module(module_name)
    kwargs = dict(help=help_text, description=module.__doc__)
    parser = sub.add_parser(verb, **kwargs) if sub is not None else VerbParser(prog=f'aeropend {verb}',
                                                                               description=module.__doc__)
    module.add_arguments(parser)
    parser.set_defaults(_main=module.main, verb=verb)
    return parser


def parse_arguments(argv: list[str]) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """(parser, namespace) of a command line; a verb's mistakes are answered by that verb's parser (its usage, one
    error line with a suggestion, exit 2), an unknown verb with the closest verb."""
    if argv and argv[0] in VERBS:       # a core verb: all_verbs() keeps the core's, so no entry point is scanned
        module_name, help_text = VERBS[argv[0]]
        parser = verb_parser(argv[0], help_text=help_text, module_name=module_name)
        return parser, parser.parse_args(argv[1:])
    verbs = all_verbs()
    if argv and argv[0] in verbs:
        parser = verb_parser(argv[0])
        return parser, parser.parse_args(argv[1:])
    parser = build_parser(argv)
    if argv and not argv[0].startswith('-'):
        import difflib
        close = difflib.get_close_matches(argv[0], list(verbs), n=1, cutoff=0.5)
        hint = f' (did you mean {close[0]}?)' if close else f' (choose from {", ".join(verbs)})'
        parser.error(f'unknown verb {argv[0]!r}{hint}')
    return parser, parser.parse_args(argv)


def debug_enabled() -> bool:
    """True when AEROPEND_DEBUG asks for full tracebacks (any value but empty, 0, false, no)."""
    return os.environ.get('AEROPEND_DEBUG', '').strip().lower() not in ('', '0', 'false', 'no')


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser, args = parse_arguments(argv)
    if not getattr(args, 'verb', None):     # bare `aeropend`: asking what it does is no mistake (help, status 0)
        parser.print_help()
        return 0
    prefix = f'aeropend {args.verb}'
    from aeropend_core.blas import single_blas_thread
    with single_blas_thread():
        return _run_verb(args, prefix)


def _run_verb(args, prefix: str) -> int:
    """Run the parsed verb; a user's mistake becomes one line and an exit status, never a traceback."""
    if debug_enabled():
        return int(args._main(args) or 0)
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning(prefix)
        try:
            return int(args._main(args) or 0)
        except AeropendError as error:
            for finding in getattr(error, 'findings', ()):          # what the data-quality gate found before it
                print(f'{prefix}: warning: {finding.message} [{finding.code}, {finding.severity}]', file=sys.stderr)
            print(f'{prefix}: error: {error}', file=sys.stderr)
            return int(getattr(error, 'exit_status', 2))
        except KeyboardInterrupt:
            print(f'{prefix}: interrupted', file=sys.stderr)
            return 130
        except BrokenPipeError:
            # the reader of our standard output went away (`aeropend simulate | head`): not an error of ours
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 141
        except OSError as error:
            print(f'{prefix}: error: {_os_error_text(error)}', file=sys.stderr)
            return 1
        except MemoryError:
            print(f'{prefix}: error: out of memory; use a shorter record (or --start/--stop)', file=sys.stderr)
            return 1
        except Exception as error:  # noqa: BLE001 - a bug: one line that says so, the traceback on request
            where = _innermost_frame(error)
            print(f'{prefix}: internal error: {type(error).__name__}: {error}{where}\n'
                  f'{prefix}: this is a bug in aeropend, not a problem with your input. Run the same command with '
                  f'AEROPEND_DEBUG=1 for the traceback and please report it.', file=sys.stderr)
            return 1


def _os_error_text(error: OSError) -> str:
    """'<file>: <reason>' of an OSError, e.g. 'run.csv: No space left on device (errno 28)'."""
    reason = error.strerror or str(error)
    code = f' (errno {error.errno})' if error.errno else ''
    target = error.filename if error.filename is not None else ''
    return f'{target}: {reason}{code}' if target else f'{reason}{code}'


def _innermost_frame(error: BaseException) -> str:
    """' (at file.py:123 in function)' of the innermost traceback frame, for the one-line bug report."""
    tb = error.__traceback__
    if tb is None:
        return ''
    while tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code
    return f' (at {os.path.basename(code.co_filename)}:{tb.tb_lineno} in {code.co_name})'


def _one_line_warning(prefix: str):
    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f'{prefix}: warning: {message}', file=sys.stderr if file is None else file)
    return show


if __name__ == '__main__':
    sys.exit(main())
