"""List the catalog of physical effects: name, parameters with SI units, the equation it enters, its signature."""
from __future__ import annotations

import argparse

from aeropend_core.model.effects import CATALOG


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from aeropend_core.cli._checks import add_json_argument
    add_json_argument(parser, 'the catalog')


def main(args: argparse.Namespace) -> int:
    if args.json:
        from aeropend_core.cli._checks import check_json_target
        from aeropend_core.present.json_output import write_json
        check_json_target(args.json)
        write_json(args.json, {name: {'description': e.description, 'signature': e.signature, 'kind': e.kind,
                                      'equation': e.equation,
                                      'parameters': {p.name: {'unit': p.unit, 'description': p.description,
                                                              'typical': p.typical} for p in e.parameters}}
                               for name, e in CATALOG.items()})
        if args.json != '-':
            print(f'json: {args.json}')
        return 0
    for name, effect in CATALOG.items():
        parameters = ', '.join(f'{p.name} [{p.unit}] (typ. {p.typical:g})' for p in effect.parameters)
        print(f'{name}\n    {effect.description}\n    enters: {effect.equation}\n    parameters: {parameters}'
              f'\n    signature: {effect.signature}\n')
    return 0
