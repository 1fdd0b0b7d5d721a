"""Sphinx configuration: the documentation site of boresight (build: see CONTRIBUTING.md).

The performance page is built from the benchmarks' tables, ``bench/results/*.json``, which this
file turns into ``_generated/performance_tables.md`` on every build.
"""

import functools
import json
from pathlib import Path

import boresight

project = "boresight"
author = "the boresight developers"
release = version = boresight.__version__
extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# The tutorials run at low Nside on every build: a broken tutorial breaks the build.
nb_execution_mode = "force"
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True
exclude_patterns = ["_build", "**.ipynb_checkpoints", "_generated"]
html_theme = "furo"
html_title = "boresight"
autodoc_mock_imports = ["cupy"]  # the GPU backend documents without a GPU

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent / "bench" / "results"


def _cell(value):
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return "" if value is None else str(value)


def table_markdown(path):
    """Markdown of one benchmark's table, with its machine, date and versions."""
    data = json.loads(path.read_text())
    machine, versions = data["machine"], data["versions"]
    out = [
        f"## {data['title']}",
        "",
        f"`bench/results/{path.name}`: {data['date']}, {machine['cpu']}, "
        f"{machine['cores']} cores, {machine['memory_gib']} GiB; boresight "
        f"{versions['boresight']}, numba {versions['numba']}, ducc0 {versions['ducc0']}.",
        "",
        "| " + " | ".join(data["columns"]) + " |",
        "|" + "---|" * len(data["columns"]),
    ]
    out += [
        "| " + " | ".join(_cell(row.get(c)) for c in data["columns"]) + " |" for row in data["rows"]
    ]
    out += ["", data["notes"], ""] if data.get("notes") else [""]
    return "\n".join(out)


def performance_tables(results=RESULTS):
    """Markdown of every benchmark table, each with its machine, date and versions."""
    files = sorted(results.glob("*.json"))
    if not files:
        return "No benchmark has written its table yet: run a script of `bench/`.\n"
    return "\n".join(table_markdown(path) for path in files)


def _write_performance(app):
    """The performance page's tables, and each table alone (``_generated/<name>.md``) for the
    guide's pages to include."""
    target = HERE / "_generated" / "performance_tables.md"
    target.parent.mkdir(exist_ok=True)
    target.write_text(performance_tables())
    for path in sorted(RESULTS.glob("*.json")):
        (target.parent / f"{path.stem}.md").write_text(table_markdown(path))


def _skip_field(app, what, name, obj, skip, options):
    """Leave out a NamedTuple's or dataclass's fields: its Parameters section documents them,
    and a target per field would catch every ``shape (n,)`` of a type as a link to one ``n``."""
    method = callable(obj) or isinstance(obj, (property, functools.cached_property))
    if what == "class" and name.islower() and not method:  # a field, not a method or CONSTANT
        return True
    return None


def setup(app):
    app.connect("builder-inited", _write_performance)
    app.connect("autodoc-skip-member", _skip_field)
