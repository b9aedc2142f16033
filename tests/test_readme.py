"""The README's Python examples run as written."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


RUNNABLE = [b for b in BLOCKS if not b.startswith("# with your own files")]


@pytest.mark.parametrize("index", range(len(RUNNABLE)))
def test_readme_python_block_runs(index):
    exec(compile(RUNNABLE[index], f"README.md block {index}", "exec"), {})


def test_readme_has_the_two_setup_commands_and_ci_runs_the_test_one():
    text = README.read_text()
    ci = (README.parent / ".ci" / "run").read_text()
    test_cmd = 'pip install torch==2.13.0 && pip install ".[test]" && python -m pytest -n 2'
    assert test_cmd in text and test_cmd in ci
    assert "torchquat convert examples/data/sample_trajectory.tum" in text
