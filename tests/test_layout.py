"""The package's layout holds what docs/architecture.md says of it: each module imports only from
its own layer or below, no import cycle (type-level imports included), imports at the top of the
module, keyword-only options on wide public functions, a test file per module, and every module
on the architecture page. The tests run this checkout."""

import ast
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "boresight"

#: the layers, lowest first: a module may import from its own layer and the ones below
LAYERS = {
    "base": {"constants", "data", "validation", "_util"},
    "kernels": {"kernels", "harmonics"},
    "inputs": {
        "cosmology",
        "sky",
        "instrument",
        "scan",
        "frames",
        "schedule",
        "pointing",
        "masks",
        "noise",
    },
    "engine": {"evaluation", "mapmaking", "mitigation", "engine"},
    "analysis": {"spectra", "coupling", "predict", "moments"},
    "jobs": {"config", "jobs"},
    "design": {"design"},
    "outputs": {"outputs"},
    "commands": {"commands"},
    "cli": {"cli"},
}
#: imports inside a function, and why each is there
DEFERRED = {
    ("boresight.cli", "boresight"): "Ctrl-C is handled before anything heavy is imported",
    ("boresight.cli", "boresight.commands"): "Ctrl-C is handled before numba is imported",
    ("boresight.cli", "boresight.validation"): "Ctrl-C is handled before numpy is imported",
    ("boresight.kernels.contract", "boresight.kernels.cpu"): "a backend compiles when chosen",
    ("boresight.kernels.contract", "boresight.kernels.gpu"): "the GPU backend needs CuPy",
}
#: modules whose tests live elsewhere than tests/.../test_<module>.py, and where
TESTED_ELSEWHERE = {
    "cli": "tests/cli",  # the command line end to end
    "kernels.gpu": "tests/test_gpu.py",  # the GPU backend, on a GPU
}
#: decorators of compiled kernels, whose signatures numba fixes
COMPILED = {"njit", "jit", "register_jitable", "vectorize", "guvectorize", "generated_jit"}


def _modules():
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _layer(module):
    top = module.split(".")[1] if "." in module else None
    if top is None:  # the package itself: __version__ and the lazy exports
        return 0
    return next(i for i, names in enumerate(LAYERS.values()) if top in names)


def _imports(module):
    """(imported module, the function it is imported in or None) of every boresight import."""
    path = MODULES[module]
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = []

    def visit(node, function):
        for child in ast.iter_child_nodes(node):
            inner = child.name if isinstance(child, ast.FunctionDef) else function
            if isinstance(child, ast.ImportFrom):
                base = package[: len(package) - child.level + 1] if child.level else []
                target = ".".join(base + ([child.module] if child.module else []))
                for alias in child.names:
                    name = f"{target}.{alias.name}"
                    found.append((name if name in MODULES else target, function))
            elif isinstance(child, ast.Import):
                found.extend((alias.name, function) for alias in child.names)
            visit(child, inner)

    visit(ast.parse(path.read_text()), None)
    return [(m, f) for m, f in found if m in MODULES and m != module]


def test_every_module_has_a_layer():
    tops = {m.split(".")[1] for m in MODULES if "." in m}
    named = set().union(*LAYERS.values())
    assert tops - named == set() and named - tops == set()


@pytest.mark.parametrize("module", sorted(MODULES))
def test_a_module_imports_only_from_its_layer_and_below(module):
    higher = [m for m, _ in _imports(module) if _layer(m) > _layer(module)]
    assert higher == [], f"{module} imports from a higher layer"


def test_no_import_cycles():
    graph = {m: {d for d, _ in _imports(m)} for m in MODULES}
    state = {}

    def walk(node, path):
        state[node] = "open"
        for dep in graph[node]:
            if dep.startswith(node + "."):  # a package re-exports its own modules
                continue
            if state.get(dep) == "open":
                pytest.fail(" -> ".join([*path, dep]))
            if dep not in state:
                walk(dep, [*path, dep])
        state[node] = "done"

    for module in MODULES:
        if module not in state:
            walk(module, [module])


def test_imports_are_at_the_top_unless_a_reason_is_given():
    deferred = {(m, d) for m in MODULES for d, function in _imports(m) if function is not None}
    assert deferred == set(DEFERRED)


def _public_functions():
    for module, path in MODULES.items():
        if any(part.startswith("_") for part in module.split(".")[1:]) or ".kernels" in module:
            continue  # private modules and the kernels, whose contract numba fixes
        tree = ast.parse(path.read_text())
        scopes = [(tree.body, "")] + [
            (node.body, f"{node.name}.")
            for node in tree.body
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_")
        ]
        for body, prefix in scopes:
            for node in body:
                if not isinstance(node, ast.FunctionDef) or node.name.startswith("_"):
                    continue
                names = {
                    ast.unparse(d.func if isinstance(d, ast.Call) else d).split(".")[-1]
                    for d in node.decorator_list
                }
                if names & COMPILED:
                    continue
                yield f"{module}.{prefix}{node.name}", node.args, bool(prefix)


def test_wide_public_functions_take_keyword_only_options():
    """More than four parameters: the options after the essential ones are keyword-only, and at
    most five are positional (as NaMaster's NmtField(mask, maps, *, ...))."""
    wide = []
    for name, args, method in _public_functions():
        positional = args.posonlyargs + args.args
        positional = positional[1:] if method else positional
        total = len(positional) + len(args.kwonlyargs)
        if total > 4 and (not args.kwonlyargs or len(positional) > 5) and not args.kwarg:
            wide.append(f"{name} ({len(positional)} positional)")
    assert wide == []


def test_every_module_with_logic_has_a_test_file():
    """tests/ mirrors the package: boresight/x.py is tested in tests/test_x.py, a subpackage's
    module boresight/p/x.py in tests/p/test_x.py; the command line end to end in tests/cli/."""
    missing = []
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text())
        logic = any(isinstance(n, (ast.FunctionDef, ast.ClassDef)) for n in tree.body)
        parts = module.split(".")[1:]
        if not parts or not logic or parts[-1].startswith("_") or parts[0] == "commands":
            continue
        elsewhere = TESTED_ELSEWHERE.get(".".join(parts))
        where = ROOT / (elsewhere or Path("tests", *parts[:-1], f"test_{parts[-1]}.py"))
        if not where.exists():
            missing.append(str(where.relative_to(ROOT)))
    assert missing == []


def test_every_command_has_an_end_to_end_test():
    from boresight import commands

    text = "".join(p.read_text() for p in (ROOT / "tests" / "cli").glob("test_*.py"))
    assert [c.NAME for c in commands.ALL if f'"{c.NAME}"' not in text] == []


def test_the_architecture_page_draws_these_layers():
    """docs/architecture.md's table of layers is LAYERS: the picture a reader sees is the one
    the imports are held to."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    drawn = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2 and cells[0] in LAYERS:
            drawn[cells[0]] = {m.split(".")[0] for m in re.findall(r"`([\w.]+)`", cells[1])}
    assert drawn == {name: modules for name, modules in LAYERS.items()}


def test_the_architecture_page_names_every_module():
    text = (ROOT / "docs" / "architecture.md").read_text()
    short = {m.removeprefix("boresight.") for m in MODULES if m != "boresight"}
    assert sorted(m for m in short if not re.search(rf"`{re.escape(m)}`", text)) == []


def test_no_tracker_issue_numbers_in_code_or_tests():
    pattern = re.compile(r"\bissues? #?\d+|\(#\d+\)", re.IGNORECASE)
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for folder in ("boresight", "tests", "bench")
        for p in (ROOT / folder).rglob("*.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert hits == []


def test_the_public_api_of_the_docstring_exists():
    import boresight

    listed = re.findall(r"``(\w+)``", boresight.__doc__)
    assert set(listed) >= set(boresight.__all__) - {"__version__"}
    for name in boresight.__all__:
        assert getattr(boresight, name) is not None, name


def test_every_benchmark_writes_its_table_as_json():
    """bench/bench_*.py report through bench/_table.py, which writes bench/results/NAME.json."""
    lazy = [
        p.name
        for p in sorted((ROOT / "bench").glob("bench_*.py"))
        if "report(" not in p.read_text()
    ]
    assert lazy == []


def test_the_tests_and_the_processes_they_start_import_this_checkout():
    """``python -m boresight.cli`` started from the checkout (the CLI, kill and compile tests)
    imports the checkout's boresight, and so must the tests (the README installs it with
    ``pip install -e``): two copies would each compile their own numba kernels."""
    import boresight

    code = "import importlib.util as u; print(u.find_spec('boresight').origin)"
    found = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    here = ROOT / "boresight" / "__init__.py"
    assert Path(boresight.__file__).resolve() == Path(found.stdout.strip()).resolve() == here


def test_a_plates_mode_is_compared_only_in_its_own_module():
    """hwp.mode and hwp.step are asked through HWP's properties (present, spinning, stepped,
    steps_with_repeats, label) everywhere but boresight/instrument/hwp.py: no string comparison of them
    elsewhere."""
    found = []
    for module, path in MODULES.items():
        if module == "boresight.instrument.hwp":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            sides = [node.left, *node.comparators]
            attribute = any(
                isinstance(x, ast.Attribute) and x.attr in ("mode", "step") for x in sides
            )
            text = any(isinstance(x, ast.Constant) and x.value in ("none", "continuous", "stepped",
                       "ces", "day", "repeat") for x in sides)  # fmt: skip
            if attribute and text:
                found.append(f"{module}:{node.lineno}")
    assert found == []


def test_no_private_name_is_imported_across_modules():
    """A name with a leading underscore stays in its module (private modules such as
    commands._common are imported whole, as plumbing)."""
    found = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (
                node.level or "boresight" in (node.module or "")
            ):
                found += [
                    f"{module}: {a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                    and f"{node.module}.{a.name}".split(".")[-1] not in PRIVATE_MODULES
                ]  # fmt: skip
    assert found == []


#: private modules, imported whole
PRIVATE_MODULES = {"_common"}


#: the sizes a reader can hold: entries at the package's top, lines of a module, lines of a
#: command's function (its docstring included)
MAX_TOP_ENTRIES, MAX_MODULE_LINES, MAX_COMMAND_FUNCTION_LINES = 30, 800, 80


def test_the_package_top_modules_and_commands_stay_small():
    """At most 30 entries at boresight/'s top (modules and stage packages), no module over 800
    lines, no function of a command over 80 lines: a command parses, calls one library job and
    writes its files."""
    top = sorted(
        p.name for p in PACKAGE.iterdir() if p.name != "__pycache__" and not p.name.startswith(".")
    )
    assert len(top) <= MAX_TOP_ENTRIES, top
    long = {
        m: n
        for m, p in MODULES.items()
        if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert long == {}
    wide = []
    for path in sorted((PACKAGE / "commands").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                if node.end_lineno - first + 1 > MAX_COMMAND_FUNCTION_LINES:
                    wide.append(f"{path.stem}.{node.name}")
    assert wide == []


def _walk():
    spec = importlib.util.spec_from_file_location("walk", ROOT / "scripts" / "walk.py")
    walk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(walk)
    return walk.walk


@pytest.mark.parametrize("command", ["design", "hwp table"])
def test_a_design_and_the_hwp_table_never_call_a_stage_above_their_own(tmp_path, command):
    """scripts/walk.py traces every call of a command's run (a design from its budget, the HWP
    table behind a continuous plate, both small): the data flows one way, every call into a
    room the walk had left is into a lower layer (a library call: the engine asking the
    instrument per chunk), none into a higher one, and the command's own room comes first."""
    from helpers import T0, budget_file

    schedule = tmp_path / "s.toml"
    schedule.write_text(
        "sample_rate_hz = 1.0\n"
        + "".join(
            f"[[ces]]\nstart_unix = {T0 + 43200 * i}\nduration_s = 600\nelevation_deg = 50\n"
            f"az_centre_deg = {134 if i % 2 else 226}\naz_throw_deg = 40\n"
            for i in range(4)
        )
    )
    out = str(tmp_path / "out")
    if command == "design":
        argv = ["design", budget_file(tmp_path, nside=16), str(schedule), "--out", out]
    else:
        argv = ["suppression", "--hwp", "continuous", "--hwp-frequency", "0.37", "--schedule"]
        argv += [str(schedule), "--nside", "32", "--fwhm-arcmin", "450", "--out", out]
    walked = _walk()(argv, "stage")
    assert walked["code"] == 0
    assert walked["rooms"][0] == "commands" and {"engine", "moments", "predict"} <= set(
        walked["rooms"]
    )
    assert sum(walked["returns"].values()) > 0  # loops over chunks re-enter lower rooms
    assert not walked["upward"], walked["upward"]
