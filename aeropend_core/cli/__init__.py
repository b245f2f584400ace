"""The `aeropend` command: one module per verb, each with ``add_arguments(parser)`` and ``main(args) -> int``.

Verbs are imported lazily, so `aeropend simulate` never imports ROS; the ROS verbs live in `aeropend_ros`.
A user mistake (:class:`aeropend_core.errors.AeropendError`) prints one clear line and exits with status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from aeropend_core.errors import AeropendError

#: verb -> (module implementing it, one-line help)
VERBS: dict[str, tuple[str, str]] = {
    'simulate': ('aeropend_core.cli.simulate', 'simulate the rig under a Latin-hypercube excitation, write CSV'),
    'identify': ('aeropend_core.cli.identify', 'identify the rig equations with weak SINDy from CSV or MCAP'),
    'diagnose': ('aeropend_core.cli.diagnose', 'compare model and data, find the missing physical effect'),
    'effects': ('aeropend_core.cli.effects', 'list the catalog of physical effects'),
    'bag-recover': ('aeropend_core.cli.bag_recover', 'repair a bag whose recorder was killed'),
    'run': ('aeropend_ros.cli_run', 'start the node graph (sim or rig), record, identify, diagnose'),
    'monitor': ('aeropend_ros.cli_monitor', 'show live identified parameters in the terminal'),
    'calibrate': ('aeropend_ros.cli_calibrate', 'measure sensor zeros, angle scale, Ra and Kw on the rig (serial)'),
}


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The parser; only the verb named first in `argv` has its module imported."""
    parser = argparse.ArgumentParser(
        prog='aeropend',
        description='Aeropendulum rig: record, identify (weak SINDy) and diagnose missing physics.')
    sub = parser.add_subparsers(dest='verb', metavar='VERB')
    for verb, (module_name, help_text) in VERBS.items():
        if verb in argv[:1]:
            module = importlib.import_module(module_name)
            verb_parser = sub.add_parser(verb, help=help_text, description=module.__doc__,
                                         formatter_class=argparse.RawDescriptionHelpFormatter)
            module.add_arguments(verb_parser)
            verb_parser.set_defaults(_main=module.main)
        else:
            sub.add_parser(verb, help=help_text)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not args.verb:
        parser.print_help()
        return 2
    try:
        return int(args._main(args) or 0)
    except AeropendError as error:
        print(f'aeropend {args.verb}: error: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'aeropend {args.verb}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
