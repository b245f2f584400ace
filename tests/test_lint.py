"""The tree passes the one linter configuration in ruff.toml (pyflakes errors, pycodestyle, line length 120)."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_is_clean():
    ruff = shutil.which('ruff') or str(Path(sys.executable).with_name('ruff'))
    if not Path(ruff).exists():
        pytest.fail('ruff is not installed; run scripts/setup.sh')
    result = subprocess.run([ruff, 'check', '--output-format', 'concise', '.'], cwd=ROOT, capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stdout + result.stderr
