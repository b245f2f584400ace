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
}


#: entry-point group through which other packages add verbs
VERB_GROUP = 'aeropend.verbs'


def all_verbs() -> dict[str, tuple[str, str]]:
    """The core's verbs and those registered in the ``aeropend.verbs`` entry-point group (verb -> module, help)."""
    from importlib.metadata import entry_points
    verbs = dict(VERBS)
    for point in sorted(entry_points(group=VERB_GROUP), key=lambda p: p.name):
        verbs.setdefault(point.name, (point.value, _plugin_help(point.value)))
    return verbs


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


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser; only the verb named first in `argv` has its module imported."""
    parser = argparse.ArgumentParser(
        prog='aeropend',
        description='Aeropendulum rig: record, identify (weak SINDy) and diagnose missing physics.')
    sub = parser.add_subparsers(dest='verb', metavar='VERB')
    for verb, (module_name, help_text) in all_verbs().items():
        if verb in argv[:1]:
            module = importlib.import_module(module_name)
            verb_parser = sub.add_parser(verb, help=help_text, description=module.__doc__,
                                         formatter_class=argparse.RawDescriptionHelpFormatter)
            module.add_arguments(verb_parser)
            verb_parser.set_defaults(_main=module.main)
        else:
            sub.add_parser(verb, help=help_text)
    return parser


def debug_enabled() -> bool:
    """True when AEROPEND_DEBUG asks for full tracebacks (any value but empty, 0, false, no)."""
    return os.environ.get('AEROPEND_DEBUG', '').strip().lower() not in ('', '0', 'false', 'no')


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not args.verb:
        parser.print_help()
        return 2
    prefix = f'aeropend {args.verb}'
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
