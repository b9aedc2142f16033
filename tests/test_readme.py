"""The README is short, its Python examples run as written, its set-up commands are the ones CI
runs, and its links point at files that exist."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TEXT = README.read_text()
BLOCKS = re.findall(r"```python\n(.*?)```", TEXT, flags=re.S)
RUNNABLE = [b for b in BLOCKS if not b.startswith("# with your own files")]


@pytest.mark.parametrize("index", range(len(RUNNABLE)))
def test_readme_python_block_runs(index):
    exec(compile(RUNNABLE[index], f"README.md block {index}", "exec"), {})


def test_readme_has_the_two_setup_commands_and_ci_runs_the_test_one():
    ci = (ROOT / ".ci" / "run").read_text()
    test_cmd = 'pip install torch==2.13.0 && pip install ".[test]" && python -m pytest -n 2'
    main_cmd = ("pip install torch==2.13.0 && pip install . && torchquat convert "
                "examples/data/sample_trajectory.tum sample_ypr.csv --to euler:ZYX --degrees")
    section = TEXT.split("## Set-up: the two commands", 1)[1].split("\n## ", 1)[0]
    assert test_cmd in section and main_cmd in section
    assert test_cmd in ci


def test_readme_is_at_most_250_lines():
    assert len(TEXT.splitlines()) <= 250


def test_readme_links_exist():
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", TEXT):
        assert (ROOT / target).exists(), target


def test_readme_has_the_conventions_and_the_two_tables_with_their_commands():
    for thing in ("quaternion", "rotation matrix", "Euler convention", "axis-angle", "6D", "9D"):
        assert f"\n| {thing} |" in TEXT, thing
    assert "torchquat crosscheck --dtype float32" in TEXT.split("## Accuracy", 1)[1].split("\n## ", 1)[0]
    speed = TEXT.split("## Speed", 1)[1].split("\n## ", 1)[0]
    assert "torchquat bench" in speed
    assert "| op | N=1 fwd | N=1 fwd+bwd | N=1000 fwd+bwd | N=1e6 fwd | compiled 1e6 fwd |" in speed
