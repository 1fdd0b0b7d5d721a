"""Walk a command as a new maintainer would: which stages of boresight it enters, in order.

    python scripts/walk.py design examples/budget_deep_sat.toml examples/schedule_deep_sat.toml
    python scripts/walk.py --depth module design ...

Every call into a boresight function is traced (``sys.setprofile``); a call is a *room* change
when the callee's stage differs from the caller's. A stage is the package under ``boresight``
(``design``, ``predict``, ...) or the flat module (``engine``, ``sky``); with ``--depth module``
the module itself. The plumbing the layers below share (``_util``, ``kernels``, ``validation``,
``constants``, ``harmonics``, ``data``) is walked through, not counted. It prints the rooms in the
order first entered, how often the walk climbs back up to a caller in another room, and how
often it calls into a room it had already left (a *return*: counted per call, and per distinct
(from, to) edge, since a loop over chunks repeats one edge), with the commonest edges. Module
bodies run by an import are not part of the walk, nor is the building of the command line's
parser (its help strings read every stage's defaults): the walk starts at the command's own
``main``.

A return into a lower layer is a library call (the engine asks the instrument for a pair's
parameters at every chunk); the walk goes against the data's flow only where a room calls into
a layer *above* its own (``tests/test_layout.py``'s LAYERS, the order the architecture page
draws). Those calls are counted apart: the command's data flows one way where there are none.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from collections import Counter
from pathlib import Path

PLUMBING = {"_util", "kernels", "validation", "constants", "harmonics", "data"}


def room(module: str, depth: str) -> str | None:
    """The room of a module name, None outside boresight or in its plumbing."""
    parts = module.split(".")
    if parts[0] != "boresight" or len(parts) < 2 or parts[1] in PLUMBING:
        return None
    return ".".join(parts[1:]) if depth == "module" else parts[1]


def layers() -> dict[str, int]:
    """Each stage's layer, lowest 0, from ``tests/test_layout.py``'s LAYERS."""
    path = Path(__file__).resolve().parent.parent / "tests" / "test_layout.py"
    spec = importlib.util.spec_from_file_location("layout", path)
    layout = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(layout)
    return {stage: i for i, names in enumerate(layout.LAYERS.values()) for stage in names}


def walk(argv: list[str], depth: str) -> dict:
    """Run ``boresight argv`` traced; the walk's rooms, climbs and returns."""
    from boresight import cli

    order, left, returns, upward, climbs = [], set(), Counter(), Counter(), 0
    stack: list[str] = []
    level = layers()

    def profile(frame, event, arg):
        nonlocal climbs
        if event not in ("call", "return"):
            return
        here = room(frame.f_globals.get("__name__", ""), depth)
        if here is None or frame.f_code.co_name == "<module>":  # imports are not the walk
            return
        if event == "call":
            caller = stack[-1] if stack else None
            if here != caller:
                if caller is not None and level[here.split(".")[0]] > level[caller.split(".")[0]]:
                    upward[(caller, here)] += 1
                if here in order and here not in stack:
                    returns[(caller, here)] += 1
                elif here not in order:
                    order.append(here)
                if caller is not None and caller not in stack[:-1]:
                    left.add(caller)
            stack.append(here)
        elif stack:
            stack.pop()
            if stack and stack[-1] != here:
                climbs += 1

    args = cli.parser().parse_args(["-q", *argv])  # the parser's help reads every stage's
    cli.configure_logging(quiet=args.quiet, verbose=args.verbose)  # defaults: not the walk
    sys.setprofile(profile)
    try:
        code = args.main(args)
    finally:
        sys.setprofile(None)
    return {"code": code, "rooms": order, "climbs": climbs, "returns": returns, "upward": upward}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depth", choices=("stage", "module"), default="stage")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    out = walk(args.command, args.depth)
    print(f"exit {out['code']}; {len(out['rooms'])} rooms, in the order first entered:")
    print("  " + " -> ".join(out["rooms"]))
    total = sum(out["returns"].values())
    print(f"climbs back up to another room: {out['climbs']}")
    print(f"calls back into a room it had left: {total} ({len(out['returns'])} distinct edges)")
    for (src, dst), n in out["returns"].most_common(12):
        print(f"  {src} -> {dst}: {n}")
    downward = sum(n for edge, n in out["returns"].items() if edge not in out["upward"])
    print(f"  of which into a lower layer (library calls): {downward}")
    up = out["upward"]
    print(f"calls into a higher layer than the caller's: {sum(up.values())} ({len(up)} edges)")
    for (src, dst), n in up.most_common(12):
        print(f"  {src} -> {dst}: {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
