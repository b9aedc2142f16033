"""The documentation site builds with warnings as errors, documents every public name, and its
runnable Python examples run as written."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import torchquat

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
# Pages whose python blocks are whole programs (others show excerpts of the source)
RUNNABLE_PAGES = ["index.md", "conventions.md", "heads.md"]


def _blocks(page):
    text = (DOCS / page).read_text()
    return [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if not b.startswith("# with your own files")]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    for module in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
        pytest.importorskip(module, reason=f"{module} is not installed: pip install '.[docs]' builds the site")
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    return out


def test_site_builds_strict_and_documents_every_public_function(site):
    page = (site / "api_torchquat" / "index.html").read_text()
    missing = [name for name in torchquat.__all__
               if callable(getattr(torchquat, name)) and f'id="torchquat.{name}"' not in page]
    assert not missing, f"not on the API page: {missing}"
    for module, names in (("nn", ["RotationHead", "GeodesicLoss", "Convert"]),
                          ("io", ["read_poses", "write_poses", "read_bvh"]),
                          ("traj", ["associate", "interpolate", "align", "ape", "rpe", "error_statistics"])):
        html = (site / f"api_{module}" / "index.html").read_text()
        missing = [n for n in names if not re.search(rf'id="torchquat\.{module}\.(\w+\.)?{n}"', html)]
        assert not missing, f"not on the torchquat.{module} page: {missing}"


def test_site_has_its_pages(site):
    for page in ("conventions", "guarantees", "accuracy", "benchmarks", "claims", "design", "cli", "heads"):
        assert (site / page / "index.html").is_file(), page


@pytest.mark.parametrize("page,index", [(p, i) for p in RUNNABLE_PAGES for i in range(len(_blocks(p)))])
def test_docs_python_block_runs(page, index):
    block = _blocks(page)[index]
    for module in re.findall(r"^import (\w+)$|^from (\w+)", block, flags=re.M):
        name = module[0] or module[1]
        if name not in ("torch", "torchquat"):
            pytest.importorskip(name, reason=f"docs/{page} block {index} needs {name}")
    exec(compile(block, f"docs/{page} block {index}", "exec"), {})


def test_no_diaries():
    for path in [ROOT / "README.md", *DOCS.glob("*.md")]:
        assert not re.search(r"\bsessions?\b", path.read_text(), flags=re.I), path.name
    assert not (DOCS / "bench_profile.md").exists() and not (DOCS / "bench_results.md").exists()
