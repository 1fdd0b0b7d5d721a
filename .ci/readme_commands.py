"""Print the README's set-up commands, one a line: the lines of its first fenced block.

.ci/run runs them literally and in order, so the README and CI cannot drift apart.
"""

import sys
from pathlib import Path

lines = Path(sys.argv[1]).read_text().splitlines()
start = next(i for i, line in enumerate(lines) if line.startswith("```"))
end = next(i for i in range(start + 1, len(lines)) if lines[i].startswith("```"))
commands = [line.strip() for line in lines[start + 1 : end] if line.strip()]
if len(commands) != 2:
    sys.exit(f"the README's first block holds {len(commands)} commands; it should hold two")
print("\n".join(commands))
