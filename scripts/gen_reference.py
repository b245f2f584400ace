"""Write docs/reference.md from the parsers themselves: `aeropend --help`, every verb's `--help` and every node
executable's `--help`, so the reference cannot go stale (tests/test_docs.py checks the file is current).

Usage: .venv/bin/python scripts/gen_reference.py            # rewrite docs/reference.md
       .venv/bin/python scripts/gen_reference.py --check    # exit 1 when docs/reference.md is out of date
"""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / 'docs' / 'reference.md'
#: help text width [characters]; fixed so that the file does not depend on the terminal
WIDTH = 110


def node_executables() -> dict[str, str]:
    """executable -> module of the node console scripts in setup.py."""
    return dict(re.findall(r"'(\w+_node) = (aeropend_ros\.\w+):main'", (ROOT / 'setup.py').read_text('utf-8')))


def reference() -> str:
    """The whole text of docs/reference.md."""
    os.environ['COLUMNS'] = str(WIDTH)
    from aeropend_core.cli import all_verbs, build_parser, verb_parser
    from aeropend_ros.node_help import node_help
    parts = ['# Reference: every verb and every node parameter', '',
             'Generated from the argument parsers and the nodes\' parameter declarations by '
             '`.venv/bin/python scripts/gen_reference.py`; do not edit by hand (`tests/test_docs.py` fails when '
             'this file is out of date). The same text is what `aeropend VERB --help` and `NODE --help` print.', '',
             '**Verbs:** ' + ' · '.join(f'[{verb}](#aeropend-{verb})' for verb in all_verbs()), '',
             '**Nodes:** ' + ' · '.join(f'[{node}](#{node.replace("_", "_")})' for node in node_executables()), '',
             '## aeropend', '', '```text', build_parser([]).format_help().rstrip(), '```', '']
    for verb in all_verbs():
        parts += [f'## aeropend {verb}', '', '```text', verb_parser(verb).format_help().rstrip(), '```', '']
    for executable, module in node_executables().items():
        parts += [f'## {executable}', '', '```text', node_help(executable, module, width=WIDTH).rstrip(), '```', '']
    return '\n'.join(parts)


def main(argv: list[str]) -> int:
    text = reference()
    if '--check' in argv:
        current = TARGET.read_text('utf-8') if TARGET.exists() else ''
        if current != text:
            print(f'{TARGET.relative_to(ROOT)} is out of date: run .venv/bin/python scripts/gen_reference.py',
                  file=sys.stderr)
            return 1
        return 0
    TARGET.write_text(text, encoding='utf-8')
    print(f'wrote {TARGET.relative_to(ROOT)}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
