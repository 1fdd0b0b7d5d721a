"""The ``boresight`` commands, one module each: its ``run`` (the job, callable from Python with
keyword-only options), ``add_arguments`` (its flags) and ``main`` (flags -> run -> exit code).

Each job writes into a staging directory that replaces ``out_dir`` only when it has finished, so
an interrupted job leaves nothing behind, and an existing directory is kept unless ``force``.
"""

from . import (
    compare_scans,
    design,
    export_schedule,
    predict,
    reproduce,
    scan_stats,
    simulate,
    suppression,
    sweep,
)

#: every command, in the order ``boresight --help`` lists them
ALL = (
    reproduce,
    simulate,
    predict,
    scan_stats,
    compare_scans,
    sweep,
    suppression,
    design,
    export_schedule,
)
