"""docs/mocap.md's Python examples run as written."""

import re
from pathlib import Path

import pytest

PAGE = Path(__file__).resolve().parents[1] / "docs" / "mocap.md"
BLOCKS = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_mocap_page_python_block_runs(index):
    exec(compile(BLOCKS[index], f"docs/mocap.md block {index}", "exec"), {})
