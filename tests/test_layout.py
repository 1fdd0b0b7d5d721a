"""The maps of the code a newcomer reads stay complete: every module in the README's layout table,
the API reference and the architecture; every benchmark in the README. The tests run this
checkout."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MODULES = sorted(p.stem for p in (ROOT / "boresight").glob("*.py") if p.stem != "__init__")


def _readme_layout():
    readme = (ROOT / "README.md").read_text()
    return readme[readme.index("## Layout") : readme.index("The package stays one flat")]


@pytest.mark.parametrize(
    "where, text",
    [
        ("README layout", _readme_layout()),
        ("docs/api.md", (ROOT / "docs/api.md").read_text()),
        ("docs/architecture.md", (ROOT / "docs/architecture.md").read_text()),
    ],
)
def test_every_module_is_on_the_maps(where, text):
    assert [m for m in MODULES if not re.search(rf"\b{m}\b", text)] == [], where


def test_the_readme_names_every_benchmark_and_the_module_count():
    readme = (ROOT / "README.md").read_text()
    benches = {p.name for p in (ROOT / "bench").glob("bench_*.py")}
    assert benches - set(re.findall(r"bench_\w+\.py", readme)) == set()
    assert f"one flat folder of {len(MODULES)} modules" in readme


def test_the_tests_and_the_processes_they_start_import_this_checkout():
    """``python -m boresight.cli`` started from the checkout (the CLI, kill and compile tests)
    imports the checkout's boresight, and so must the tests (the README installs it with
    ``pip install -e``). After a plain ``pip install .`` pytest imported the site-packages copy:
    two copies, each compiling its own numba kernels (the suite took 37 s longer in CI)."""
    import boresight

    code = "import importlib.util as u; print(u.find_spec('boresight').origin)"
    found = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    here = ROOT / "boresight" / "__init__.py"
    assert Path(boresight.__file__).resolve() == Path(found.stdout.strip()).resolve() == here


def test_the_modules_kept_on_one_xdist_worker_exist():
    """conftest.MODULES_ON_ONE_WORKER names test files by path: a renamed one would silently be
    split between the workers again, building its module fixtures twice."""
    from conftest import MODULES_ON_ONE_WORKER

    assert all((ROOT / path).is_file() for path in MODULES_ON_ONE_WORKER), MODULES_ON_ONE_WORKER
