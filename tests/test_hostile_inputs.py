"""Small hostile inputs of issue 23, each refused clearly (one line, exit 2) instead of an internal error, a silent
exit 0, a traceback, a 27 s read or a 2 GB read:

* ``--effects-module`` with a ``.txt``, extension-less or ``.so`` file; a module that calls ``sys.exit(0)``; one that
  raises ``GeneratorExit``;
* a CSV whose first data row is text (refused after reading that row, not 10 M rows);
* a CSV line longer than any row (refused after reading 64 KiB of it, with that reason);
* the recorder's ``topics:=['']``.
"""
from __future__ import annotations

import pytest

from aeropend_core import cli
from aeropend_core.errors import AeropendError
from aeropend_core.io import recording


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv('AEROPEND_DEBUG', raising=False)


def diagnose_with_module(tmp_path, capsys, name: str, text: bytes) -> tuple[int, str]:
    module = tmp_path / name
    module.write_bytes(text)
    status = cli.main(['diagnose', str(tmp_path / 'never_read.csv'), '--effects-module', str(module)])
    captured = capsys.readouterr()
    return status, captured.out + captured.err


@pytest.mark.parametrize('name', ['effects.txt', 'effects', 'effects.so'])
def test_effects_module_that_is_not_python_source_is_refused(tmp_path, capsys, name):
    text = b'\x7fELF\x02\x01\x01' + bytes(64) if name.endswith('.so') else b'print("hello")\n'
    status, said = diagnose_with_module(tmp_path, capsys, name, text)
    assert status == 2, said
    assert 'not a Python source file (.py)' in said and name in said
    assert 'internal error' not in said and 'Traceback' not in said and len(said.strip().splitlines()) == 1


@pytest.mark.parametrize(('body', 'words'), [
    ('import sys\nsys.exit(0)\n', ('sys.exit(0)',)),
    ('import sys\nsys.exit("bye")\n', ("sys.exit('bye')",)),
    ('raise GeneratorExit("closed")\n', ('GeneratorExit', 'closed')),
])
def test_effects_module_that_exits_or_raises_is_refused(tmp_path, capsys, body, words):
    status, said = diagnose_with_module(tmp_path, capsys, 'mine.py', body.encode())
    assert status == 2, said
    assert 'loading' in said and all(word in said for word in words), said
    assert 'Traceback' not in said and len(said.strip().splitlines()) == 1


def test_csv_with_text_in_its_first_data_row_is_refused_at_once():
    """The refusal comes after the first data row, not after reading the whole file."""
    consumed = 0

    def rows():
        nonlocal consumed
        yield ['0.0', 'abc', '1', '2', '3']
        for k in range(10_000_000):
            consumed += 1
            yield [str(k * 0.002), '0.1', '1', '2', '3']
    table, ragged, non_numeric = recording._read_rows(rows(), 5)
    assert non_numeric is not None and 'data row 1' in non_numeric and "'abc'" in non_numeric
    assert consumed == 0


def test_csv_with_text_further_down_names_its_row(tmp_path):
    path = tmp_path / 'late_text.csv'
    lines = ['t,duty,armature_voltage,armature_current,angle'] + [f'{k * 0.002},0.1,1,0.2,0.1' for k in range(100)]
    lines[51] = '0.1,0.1,1,oops,0.1'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(AeropendError, match=r"non-numeric value .*'oops'.*data row 51"):
        recording.load_csv(path)


def test_a_csv_line_longer_than_any_row_is_refused_with_that_reason(tmp_path):
    path = tmp_path / 'one_line.csv'
    path.write_text('t,duty,armature_voltage,armature_current,angle\n' + '1' * (4 * recording.MAX_CSV_LINE) + '\n')
    with pytest.raises(AeropendError, match='line 2 is longer than 65536 characters') as caught:
        recording.load_csv(path)
    assert 'out of memory' not in str(caught.value)


def test_a_long_line_is_never_held_whole():
    """The reader asks for at most MAX_CSV_LINE + 1 characters of a line (the 1 GB line is never in memory)."""
    import io

    class Spy(io.StringIO):
        sizes: list = []

        def readline(self, size=-1):
            self.sizes.append(size)
            return super().readline(size)
    handle = Spy('a,b\n' + 'x' * (10 * recording.MAX_CSV_LINE))
    lines = recording._bounded_lines(handle, 'spy.csv')
    assert next(lines) == 'a,b\n'
    with pytest.raises(AeropendError, match='line 2 is longer'):
        next(lines)
    assert all(0 < size <= recording.MAX_CSV_LINE + 1 for size in Spy.sizes)


def test_cli_refuses_a_one_line_csv_with_exit_2(tmp_path, capsys):
    path = tmp_path / 'no_line_breaks.csv'
    path.write_text('1.0,' * (recording.MAX_CSV_LINE // 2))
    assert cli.main(['identify', str(path)]) == 2
    err = capsys.readouterr().err
    assert 'line 1 is longer than' in err and 'one sample per line' in err and 'out of memory' not in err


def test_recorder_refuses_an_empty_topic_name(tmp_path):
    import rclpy

    from aeropend_ros.recorder_node import RecorderNode
    from aeropend_ros.testing import private_domain_id
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id(0.3))
    try:
        for value in ("['']", "['aeropend/samples', ' ']"):
            with pytest.raises(AeropendError, match='empty topic name') as caught:
                RecorderNode(context=context, start_parameter_services=False, enable_rosout=False,
                             cli_args=['--ros-args', '-p', f'topics:={value}', '-p', f'output:={tmp_path / "bag"}'])
            assert '\n' not in str(caught.value)
        assert not (tmp_path / 'bag').exists()
    finally:
        rclpy.try_shutdown(context=context)
