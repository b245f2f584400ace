"""List the catalog of physical effects: name, parameters with SI units, the equation it enters, its signature.

With --write-discovered FILE.py, write the terms the discovery stage proposed (--term EXPRESSION, or the
``discovered_terms`` of a ``aeropend diagnose --json`` output given with --from-json) as an effects module that
``--effects-module`` loads, one registered effect per term, for you to rename and edit.

Examples:
  aeropend effects
  aeropend effects thrust_lag                   # one effect, and how to simulate it and add it to a model
  aeropend effects --write-discovered my_effects.py --term 'thrust*angular_rate'
  aeropend effects --write-discovered my_effects.py --from-json diagnosis.json
"""
from __future__ import annotations

import argparse

from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import CATALOG


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('effect', nargs='*', metavar='EFFECT',
                        help='show only these effects, with the commands that simulate them and add them to the '
                             'model (default: the whole catalog)')
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the catalog')
    parser.add_argument('--write-discovered', metavar='FILE.py', default=None,
                        help='write the discovered terms (--term, --from-json) as an effects module for '
                             '--effects-module')
    parser.add_argument('--term', action='append', default=[], metavar='EXPRESSION',
                        help='a discovered term to write (repeatable), e.g. \'thrust*angular_rate\'')
    parser.add_argument('--from-json', metavar='DIAGNOSIS.json', default=None,
                        help='take the terms from the "discovered_terms" of `aeropend diagnose --json` output')


def _write_discovered(args: argparse.Namespace) -> int:
    from pathlib import Path

    from aeropend_core.diagnosis.discovery import find_term
    from aeropend_core.present.discovery_text import effect_module_text
    expressions = list(args.term)
    if args.from_json:
        import json
        from aeropend_core.io.inputs import read_input_text
        try:         # a FIFO or device is refused (it would block); a JSON nested too deep too (RecursionError)
            data = json.loads(read_input_text(Path(args.from_json), '--from-json', 64 * 1024 * 1024))
        except RecursionError:
            raise AeropendError(f'--from-json {args.from_json} nests too deep to be a diagnosis; give the file '
                                'written by `aeropend diagnose FILE --json OUT.json`') from None
        except (OSError, ValueError) as error:
            raise AeropendError(f'--from-json {args.from_json}: cannot read it ({error}); give the file written by '
                                '`aeropend diagnose FILE --json OUT.json`') from None
        if not isinstance(data, dict) or not isinstance(data.get('discovered_terms'), list):
            raise AeropendError(f'--from-json {args.from_json} has no "discovered_terms" list; give the output of '
                                '`aeropend diagnose FILE --json OUT.json`')
        expressions += [entry.get('expression', '') for entry in data['discovered_terms'] if isinstance(entry, dict)]
    if not expressions:
        raise AeropendError('--write-discovered needs terms: give --term EXPRESSION or --from-json DIAGNOSIS.json '
                            '(a diagnosis with discovered terms)')
    if not args.write_discovered.endswith('.py'):
        raise AeropendError(f'--write-discovered {args.write_discovered}: the file must end in .py (it is loaded '
                            'with --effects-module)')
    terms = []
    for text in expressions:
        term = find_term(text)
        if term not in terms:
            terms.append(term)
    from aeropend_core.io.atomic import atomic_write
    text = effect_module_text(terms)
    try:
        atomic_write(args.write_discovered, lambda handle: handle.write(text))
    except OSError as error:
        raise AeropendError(f'--write-discovered {args.write_discovered}: cannot write it ({error.strerror or error})'
                            '; give a writable path') from None
    names = ', '.join(f'discovered_{t.slug}' for t in terms)
    print(f'wrote {args.write_discovered}: effects {names} (load with --effects-module {args.write_discovered} '
          f'--add NAME)')
    return 0


def main(args: argparse.Namespace) -> int:
    if args.write_discovered:
        return _write_discovered(args)
    if args.term or args.from_json:
        raise AeropendError('--term and --from-json go with --write-discovered FILE.py')
    from aeropend_core.model.effects import check_effect_names
    names = check_effect_names(args.effect, 'aeropend effects')   # a misspelt name: refused with the closest one
    shown = {name: CATALOG[name] for name in names} if names else CATALOG
    if args.json:
        from aeropend_core.cli._checks import check_json_target
        from aeropend_core.present.json_output import write_json
        check_json_target(args.json)
        write_json(args.json, {name: {'description': e.description, 'signature': e.signature, 'kind': e.kind,
                                      'equation': e.equation,
                                      'parameters': {p.name: {'unit': p.unit, 'description': p.description,
                                                              'typical': p.typical} for p in e.parameters}}
                               for name, e in shown.items()})
        if args.json != '-':
            print(f'json: {args.json}')
        return 0
    for name, effect in shown.items():
        parameters = ', '.join(f'{p.name} [{p.unit}] (typ. {p.typical:g})' for p in effect.parameters)
        print(f'{name}\n    {effect.description}\n    enters: {effect.equation}\n    parameters: {parameters}'
              f'\n    signature: {effect.signature}')
        if names:          # one asked for by name: what to do with it next
            hidden = (f'--effect {name}={effect.parameters[0].typical:g}' if len(effect.parameters) == 1 else
                      ' '.join(f'--effect {name}.{p.name}={p.typical:g}' for p in effect.parameters))
            print(f'    simulate it (hidden from the model): aeropend simulate -o {name}.csv {hidden}'
                  f'\n    put it in the model of a diagnosis: aeropend diagnose RECORDING --add {name}')
        print()
    return 0
