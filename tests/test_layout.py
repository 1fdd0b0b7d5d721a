"""The maps of the code a newcomer reads stay complete: every module in the README's layout table,
the API reference and the architecture; every benchmark in the README."""

import re
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
