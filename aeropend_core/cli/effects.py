"""List the catalog of physical effects: name, parameters with SI units, the equation it enters, its signature."""
from __future__ import annotations

import argparse
import json

from aeropend_core.model.effects import CATALOG


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--json', action='store_true', help='print the catalog as JSON')


def main(args: argparse.Namespace) -> int:
    if args.json:
        print(json.dumps({name: {'description': e.description, 'signature': e.signature, 'kind': e.kind,
                                 'equation': e.equation,
                                 'parameters': {p.name: {'unit': p.unit, 'description': p.description,
                                                         'typical': p.typical} for p in e.parameters}}
                          for name, e in CATALOG.items()}, indent=2))
        return 0
    for name, effect in CATALOG.items():
        parameters = ', '.join(f'{p.name} [{p.unit}] (typ. {p.typical:g})' for p in effect.parameters)
        print(f'{name}\n    {effect.description}\n    enters: {effect.equation}\n    parameters: {parameters}'
              f'\n    signature: {effect.signature}\n')
    return 0
