"""The README and the user guide in docs/ "build" offline and every command they show runs (issue #24 item 1).

- every relative link and every ``#anchor`` resolves (GitHub's heading slugs); the only links allowed to point at a
  missing file are the guide pages other work adds (:data:`PAGES_ADDED_ELSEWHERE`);
- docs/reference.md is what ``scripts/gen_reference.py`` generates from the parsers now (it cannot go stale);
- the README is at most ~200 lines and starts with the two commands, the second being exactly what ``.ci/run`` runs;
- every fenced ``bash`` / ``console`` block runs, in a scratch folder, with ``.venv/bin`` first on PATH (as after
  ``source .venv/bin/activate``) and this tree on PYTHONPATH; a block that cannot (hardware, a ROS 2 install, many
  minutes) has a visible ``<!-- not run: reason -->`` line above it. Blocks that start ROS nodes are marked ``ros``,
  blocks that diagnose or run the graph ``slow``;
- the examples in every verb's ``--help`` are valid command lines for that verb's parser.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / 'docs').glob('*.md'))
PAGES = [ROOT / 'README.md', *DOCS, ROOT / 'bench' / 'results' / 'README.md']
#: guide pages written on other branches; a link to one may point at a file not here yet
PAGES_ADDED_ELSEWHERE = {'bags.md', 'rig-link.md', 'log-import.md', 'reduced-model.md', 'uncertainty.md', 'live.md',
                         'report.md'}
NOT_RUN = re.compile(r'<!--\s*not run:\s*(.+?)\s*-->')
FENCE = re.compile(r'^```(\w*)\s*$')


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped (not - and _), spaces to hyphens."""
    text = re.sub(r'`|\*\*|\*', '', heading.strip().lower())
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', text)
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(path: Path) -> set[str]:
    found: set[str] = set()
    seen: dict[str, int] = {}
    in_code = False
    for line in path.read_text(encoding='utf-8').splitlines():
        if FENCE.match(line):
            in_code = not in_code
            continue
        match = re.match(r'^(#{1,6})\s+(.*)$', line)
        if match and not in_code:
            base = slug(match.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f'{base}-{count}')
    return found


def prose(path: Path) -> str:
    """The page without its fenced blocks and inline code (links there are examples, not links)."""
    out, in_code = [], False
    for line in path.read_text(encoding='utf-8').splitlines():
        if FENCE.match(line):
            in_code = not in_code
            continue
        if not in_code:
            out.append(re.sub(r'`[^`]*`', '', line))
    return '\n'.join(out)


def links(path: Path) -> list[str]:
    return re.findall(r'\[[^\]]*\]\(([^)\s]+)\)', prose(path))


@pytest.mark.parametrize('page', PAGES, ids=rel)
def test_every_relative_link_and_anchor_resolves(page):
    problems = []
    for target in links(page):
        if re.match(r'[a-z]+:', target):             # http:, https:, mailto: - not checked offline
            continue
        file_part, _, anchor = target.partition('#')
        destination = (page.parent / file_part).resolve() if file_part else page
        if not destination.exists():
            if destination.name in PAGES_ADDED_ELSEWHERE and destination.parent == ROOT / 'docs':
                continue
            problems.append(f'{target}: no such file')
            continue
        if anchor and destination.suffix == '.md' and anchor not in anchors(destination):
            problems.append(f'{target}: no heading with anchor #{anchor} in {rel(destination)}')
    assert not problems, f'{rel(page)}:\n' + '\n'.join(problems)


def test_every_guide_page_is_reachable_from_the_index():
    linked = {Path(target.partition('#')[0]).name for target in links(ROOT / 'docs' / 'index.md')}
    missing = [p.name for p in DOCS if p.name not in linked and p.name != 'index.md']
    assert not missing, f'docs/index.md does not link {missing}'


def test_reference_is_generated_from_the_current_parsers():
    sys.path.insert(0, str(ROOT / 'scripts'))
    try:
        import gen_reference
    finally:
        sys.path.pop(0)
    current = (ROOT / 'docs' / 'reference.md').read_text(encoding='utf-8')
    assert current == gen_reference.reference(), ('docs/reference.md is out of date: run .venv/bin/python '
                                                  'scripts/gen_reference.py')


def test_readme_is_short_and_starts_with_the_two_commands():
    text = (ROOT / 'README.md').read_text(encoding='utf-8')
    lines = text.splitlines()
    assert len(lines) <= 200, f'README.md has {len(lines)} lines'
    run = 'bash scripts/setup.sh && .venv/bin/aeropend run'
    test = 'bash scripts/setup.sh && .venv/bin/python -m pytest -q'
    assert run in lines[:40] and test in lines[:40]
    ci = (ROOT / '.ci' / 'run').read_text(encoding='utf-8').strip().splitlines()[-1]
    assert ci == test, f'.ci/run runs {ci!r}, the README says {test!r}'
    assert 'source .venv/bin/activate' in text
    assert '.venv/bin/python -m pytest -q -m "not slow and not ros"' in text


# ------------------------------------------------------------------------------------------------------------------
# The commands
# ------------------------------------------------------------------------------------------------------------------
def blocks(page: Path) -> list[tuple[int, str, str, str | None]]:
    """(line, language, body, not-run reason) of the fenced bash/console blocks of a page."""
    found = []
    lines = page.read_text(encoding='utf-8').splitlines()
    index = 0
    while index < len(lines):
        match = FENCE.match(lines[index])
        if match and match.group(1):
            start = index
            index += 1
            body = []
            while index < len(lines) and not lines[index].startswith('```'):
                body.append(lines[index])
                index += 1
            if match.group(1) in ('bash', 'console', 'sh', 'shell'):
                before = next((line for line in reversed(lines[:start]) if line.strip()), '')
                reason = NOT_RUN.search(before)
                found.append((start + 1, match.group(1), '\n'.join(body), reason.group(1) if reason else None))
        index += 1
    return found


def commands(language: str, body: str) -> list[str]:
    """The commands of a block: continuation lines joined; in a console block only the `$ ` lines."""
    result: list[str] = []
    pending = ''
    for line in body.splitlines():
        if language == 'console' and not pending:
            if not line.startswith('$ '):
                continue
            line = line[2:]
        if line.rstrip().endswith('\\'):
            pending += line.rstrip()[:-1] + ' '
            continue
        command = (pending + line).strip()
        pending = ''
        if command and not command.startswith('#'):
            result.append(command)
    return result


ALL_BLOCKS = [(page, line, language, body, reason) for page in PAGES for line, language, body, reason in blocks(page)]
RUN_BLOCKS = {}
for _page, _line, _language, _body, _reason in ALL_BLOCKS:
    if _reason is None:
        RUN_BLOCKS.setdefault('\n'.join(commands(_language, _body)), f'{rel(_page)}:{_line}')   # each once


def block_marks(script: str) -> list:
    marks = []
    if re.search(r'\baeropend (run|monitor)\b|_node\b|\bros2\b', script):
        marks.append(pytest.mark.ros)
    if re.search(r'\baeropend (run|diagnose)\b', script):
        marks.append(pytest.mark.slow)
    return marks


def docs_environment() -> dict[str, str]:
    """The environment of a docs block: this host's ROS settings on a private domain (a block that runs the graph
    meets no other test's nodes). Kept out of the test's own source, so that tests/conftest.py puts only the blocks
    marked `ros` above (a graph, a node) in the real-time group, not every block."""
    from aeropend_ros._ros_env import local_ros_environment
    from tests.ros_helpers import private_domain_id
    return local_ros_environment(domain_id=private_domain_id())


def test_not_run_blocks_are_few_and_say_why():
    skipped = [(rel(page), line, reason) for page, line, _, _, reason in ALL_BLOCKS if reason is not None]
    assert all(len(reason) > 15 for _, _, reason in skipped), skipped
    assert len(skipped) <= 20, skipped                     # the list stays short


@pytest.mark.parametrize('script, where', [pytest.param(script, where, id=where, marks=block_marks(script))
                                           for script, where in RUN_BLOCKS.items()])
def test_every_command_in_the_docs_runs(tmp_path, script, where):
    env = docs_environment()
    venv_bin = Path(sys.executable).parent
    env['PATH'] = os.pathsep.join([str(venv_bin), env.get('PATH', '')])       # as after source .venv/bin/activate
    env['PYTHONPATH'] = os.pathsep.join([str(ROOT), env.get('PYTHONPATH', '')])
    env['MPLBACKEND'] = 'Agg'
    for name in ('config', 'scripts', 'launch', 'firmware', 'bench', 'samples', 'setup.py', 'requirements.txt'):
        (tmp_path / name).symlink_to(ROOT / name)               # the repository's files, read where the docs say
    result = subprocess.run(['bash', '-euo', 'pipefail', '-c', script], cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=900, check=False)
    assert result.returncode == 0, f'{where}: exit {result.returncode}\n{script}\n{result.stdout[-3000:]}' \
                                   f'\n{result.stderr[-3000:]}'
    assert 'Traceback' not in result.stderr, result.stderr


# ------------------------------------------------------------------------------------------------------------------
# The examples of each verb's --help
# ------------------------------------------------------------------------------------------------------------------
def help_examples() -> list[tuple[str, list[str]]]:
    from aeropend_core.cli import all_verbs, verb_parser
    found = []
    for verb in all_verbs():
        text = verb_parser(verb).format_help()
        for line in text.splitlines():
            match = re.match(r'^\s+aeropend (\S+)(.*)$', line)
            if match and match.group(1) in all_verbs():
                command = match.group(2).split('#', 1)[0].split('|', 1)[0]
                found.append((match.group(1), shlex.split(command)))
    return found


@pytest.mark.slow
def test_every_help_example_is_a_valid_command_line_for_its_verb():
    from aeropend_core.cli import verb_parser
    examples = help_examples()
    assert len(examples) >= 20
    for verb, argv in examples:
        try:
            verb_parser(verb).parse_args(argv)
        except SystemExit as stop:
            raise AssertionError(f'`aeropend {verb} {shlex.join(argv)}` (an example in the help) is refused: '
                                 f'exit {stop.code}') from None


def inline_commands() -> list[tuple[str, str, list[str]]]:
    """(page, text, argv) of every inline `aeropend VERB ...` in the prose of the README and the guide, except those
    written with placeholders (<...>, [...], ..., NAME, FILE)."""
    from aeropend_core.cli import all_verbs
    found = []
    for page in PAGES:
        text = page.read_text(encoding='utf-8')
        for span in re.findall(r'`(aeropend [^`]+)`', text):
            words = span.split('#', 1)[0].split('|', 1)[0].split('&&', 1)[0].strip()
            if re.search(r'<|\[|\.\.\.|…|\b[A-Z]{2,}[A-Z_.]*\b', words):
                continue
            try:
                argv = shlex.split(words)[1:]
            except ValueError:
                continue
            if argv and argv[0] in all_verbs() and '--help' not in argv and '-h' not in argv:
                found.append((rel(page), span, argv))
    return found


@pytest.mark.slow
def test_every_inline_command_in_the_prose_is_a_valid_command_line():
    """Inline examples (`aeropend diagnose run.csv --json`) use options that exist with values they accept."""
    from aeropend_core.cli import verb_parser
    refused = []
    examples = inline_commands()
    assert len(examples) >= 30
    import contextlib
    import io
    for page, span, argv in examples:
        errors = io.StringIO()
        try:
            with contextlib.redirect_stderr(errors):
                verb_parser(argv[0]).parse_args(argv[1:])
        except SystemExit:
            message = errors.getvalue().strip().splitlines()[-1]
            # a mention of a verb or an option (`aeropend identify`, `aeropend run --rig`) is not a command line
            if 'are required' not in message and 'expected one argument' not in message:
                refused.append(f'{page}: `{span}`: {message}')
    assert not refused, 'refused by the parser:\n' + '\n'.join(refused)
