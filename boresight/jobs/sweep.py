"""Sweeps and ensembles: a grid or list over any config field, each point a task, run serially,
on a local Dask cluster or on an existing Dask scheduler.

A sweep file (TOML) names a base study and the values to sweep:

    base = "gain_deep.toml"            # a study config, relative to the sweep file
    mode = "grid"                      # "grid" (all combinations) or "list" (zipped)
    [parameters]
    pbr_angle_deg = [0, 45, 70, 89, 90]   # shorthand: scan.rotations_deg = [0, angle]
    "sky.seed" = [1, 2, 3]                # any dotted config key

Every finished point is written at once (atomically) to DIR/points/; a re-run of the same sweep
skips them, so an interrupted sweep loses only its running points and a re-run completes it with
exactly the rows an uninterrupted run gives. Rows are sorted by point, so the table does not depend
on the order in which workers finish.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import logging
import os
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .. import __version__, coupling, masks, predict
from .._util import interrupts, io, tasks
from ..config import parse_study, read_toml
from ..cosmology import load_spectra
from ..validation import ConfigError, OutputExistsError
from . import residual, resources

log = logging.getLogger(__name__)

#: the columns of a point's rows
POINT_COLUMNS = ("ell_lo", "ell_hi", *residual.Residual.COLUMNS, "delta_r", "predicted_delta_r")


def load_sweep(path: str) -> tuple[dict, str, list[dict]]:
    """Read and validate a sweep file; every point is checked as a study before any work.

    Parameters
    ----------
    path : str

    Returns
    -------
    base : dict
        The base study's raw tables.
    base_dir : str
        Directory of the base study (relative paths start there).
    points : list of dict
        The overrides of each point.

    Raises
    ------
    ConfigError
        Naming the sweep file, the point or the key.
    """
    spec = read_toml(path, "sweep")
    unknown = set(spec) - {"base", "mode", "parameters"}
    if unknown:
        raise ConfigError(f"unknown sweep keys {sorted(unknown)}; allowed: base, mode, parameters")
    if not isinstance(spec.get("base"), str):
        raise ConfigError(f"{path}: sweep needs base = 'STUDY.toml' (a file name)")
    if not isinstance(spec.get("parameters", {}), dict):
        raise ConfigError(f"{path}: [parameters] must be a table of value lists")
    if not isinstance(spec.get("mode", "grid"), str):
        raise ConfigError(f"{path}: mode must be 'grid' or 'list'")
    base_dir = os.path.dirname(os.path.abspath(path))
    base_path = os.path.join(base_dir, spec["base"])
    base = read_toml(base_path, "sweep base")
    points = expand(spec.get("parameters", {}), spec.get("mode", "grid"))
    for overrides in points:  # validate every point before any work
        try:
            study = parse_study(apply_overrides(base, overrides), os.path.dirname(base_path))
        except ConfigError as err:
            raise ConfigError(f"{path}, point {overrides}: {err}") from None
        if study.output.lmax <= predict.R_RANGE[0]:
            raise ConfigError(
                f"{path}: sweeps report delta_r over {predict.R_RANGE[0]} <= ell <= "
                f"{predict.R_RANGE[1]}; output.lmax = {study.output.lmax} must be > "
                f"{predict.R_RANGE[0]}"
            )
    return base, os.path.dirname(base_path), points


def expand(parameters: dict, mode: str) -> list[dict]:
    """The points of a sweep.

    Parameters
    ----------
    parameters : dict
        Dotted key (or pbr_angle_deg) -> non-empty list of values.
    mode : {"grid", "list"}
        All combinations, or the lists zipped (equal lengths).

    Returns
    -------
    list of dict
    """
    if not parameters:
        raise ConfigError("sweep [parameters] is empty")
    for key, values in parameters.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"sweep parameter {key!r} needs a non-empty list of values")
    keys = list(parameters)
    if mode == "grid":
        combos = itertools.product(*(parameters[k] for k in keys))
    elif mode == "list":
        lengths = {len(v) for v in parameters.values()}
        if len(lengths) != 1:
            raise ConfigError("mode = 'list' needs value lists of equal length")
        combos = zip(*(parameters[k] for k in keys))
    else:
        raise ConfigError(f"mode = {mode!r}; allowed: 'grid', 'list'")
    return [dict(zip(keys, c)) for c in combos]


def apply_overrides(base: dict, overrides: dict) -> dict:
    """A copy of a raw study with a point's overrides set.

    Parameters
    ----------
    base : dict
    overrides : dict
        "section.key" -> value; pbr_angle_deg -> scan.rotations_deg = [0, angle] ([0] for 0).

    Returns
    -------
    dict
    """
    raw = copy.deepcopy(base)
    for key, value in overrides.items():
        if key == "pbr_angle_deg":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"sweep pbr_angle_deg = {value!r}; allowed: numbers [deg]")
            section, name = "scan", "rotations_deg"
            value = [0.0] if value == 0 else [0.0, float(value)]
        elif key.count(".") == 1:
            section, name = key.split(".")
        else:
            raise ConfigError(f"sweep parameter {key!r}: use 'section.key' or 'pbr_angle_deg'")
        if not isinstance(raw.setdefault(section, {}), dict):
            raise ConfigError(f"sweep parameter {key!r}: [{section}] is not a table in the base")
        raw[section][name] = value
    return raw


def point_key(base: dict, base_dir: str, overrides: dict) -> str:
    """A point's file name: a hash of its whole resolved config.

    The base with the overrides applied, the size and modification time of the files it names and
    the package version: an edited base or input file is a new point, never an old result.
    Parameters as :func:`run_point`; returns 16 hexadecimal digits.
    """
    raw = apply_overrides(base, overrides)
    files = {}
    for section in raw.values():
        for value in section.values() if isinstance(section, dict) else ():
            full = os.path.join(base_dir, value) if isinstance(value, str) else None
            if full is not None and os.path.isfile(full):
                stat = os.stat(full)
                files[value] = [stat.st_size, stat.st_mtime_ns]
    text = json.dumps({"config": raw, "files": files, "version": __version__}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


_COUPLING = {}  #: this worker's last mask coupling, keyed by (mask digest, lmax, band)


def _mask_coupling(mask, lmax, band, nthreads):
    """The mask's coupling, reused while a worker's points share mask, lmax and the sky's band
    (most sweeps vary the scan or the systematics): it saves the mask's transform."""
    key = (hashlib.sha256(np.ascontiguousarray(mask).tobytes()).hexdigest(), lmax, band)
    if key not in _COUPLING:
        _COUPLING.clear()
        _COUPLING[key] = coupling.mask_coupling(mask, lmax, nthreads, band=band)
    return _COUPLING[key]


def run_point(base: dict, base_dir: str, overrides: dict) -> list[dict]:
    """Run one point's residual job (a pure task for any worker).

    Parameters
    ----------
    base : dict
    base_dir : str
    overrides : dict

    Returns
    -------
    list of dict
        One row per band: :data:`POINT_COLUMNS`, delta_r and the predicted delta_r (NaN where the
        instrument has no prediction).
    """
    study = parse_study(apply_overrides(base, overrides), base_dir)
    nside, lmax, nthreads = study.sky.nside, study.output.lmax, study.run.nthreads
    mask = masks.from_config(study.mask, nside)
    couplings = _mask_coupling(mask, lmax, study.sky.lmax, nthreads)
    job, _, _ = residual.from_study(study, mask=mask, couplings=couplings)
    template = predict.tensor_template(couplings, load_spectra(), study.sky.fwhm_arcmin, nside)
    pred = job.predicted_cl
    return residual.band_rows(
        study.output.edges(),
        job.columns(),
        delta_r=predict.delta_r(job.total, template),
        predicted_delta_r=np.nan if pred is None else predict.delta_r(pred, template),
    )


def _columns(points):
    return ["point"] + list(points[0]) + list(POINT_COLUMNS)


def _n_bands(base, base_dir, overrides):
    return len(parse_study(apply_overrides(base, overrides), base_dir).output.edges()) - 1


class CorruptPointError(ConfigError):
    """A point file that cannot be read back (truncated, edited, or of another point)."""


def read_point(path: Path, key: str, n_bands: int) -> list[dict]:
    """The rows of a finished point's file, validated.

    Parameters
    ----------
    path : pathlib.Path
    key : str
        The point's :func:`point_key`.
    n_bands : int

    Returns
    -------
    list of dict

    Raises
    ------
    CorruptPointError
        Unreadable JSON, another key, a wrong number of rows, a missing column or a non-finite
        residual.
    """
    try:
        data = json.loads(Path(path).read_text())
        rows = data["rows"]
        ok = data.get("key") == key and isinstance(rows, list) and len(rows) == n_bands
        ok = ok and all(isinstance(r, dict) and set(POINT_COLUMNS) <= set(r) for r in rows)
        ok = ok and all(
            np.isfinite(float(r[c])) for r in rows for c in POINT_COLUMNS if "pred" not in c
        )
    except (OSError, ValueError, TypeError, KeyError):
        ok = False
    if not ok:
        raise CorruptPointError(
            f"sweep point file {path} is corrupt or incomplete; re-run with --repair to "
            "recompute it"
        )
    return rows


def _open_sweep_dir(out, spec_id, force, repair):
    """Check, create or reset the sweep directory; a different or unreadable sweep.json needs
    ``force`` (start again) or, when unreadable, ``repair`` (keep the valid points)."""
    marker = out / "sweep.json"
    if out.is_dir() and any(out.iterdir()):
        if not io.is_own(out):
            raise io.OutputError(
                f"{out} holds files boresight did not write (no {io.MARKER}); choose another --out"
            )
        try:
            same = json.loads(marker.read_text())["keys"] == spec_id["keys"]
            readable = True
        except (OSError, ValueError, TypeError, KeyError):
            same = readable = False
        if not same and force:
            io.remove_output_dir(out)
        elif not same and not (repair and not readable):
            why = "holds another sweep" if readable else "has an unreadable sweep.json"
            raise OutputExistsError(f"{out} {why}; use --force to start again or --repair")
    io.make_output_dir(out)
    (out / "points").mkdir(exist_ok=True)
    for stale in (out / "points").glob(".*"):  # temp files of a write that was killed
        stale.unlink()
    io.write_json(marker, spec_id)


def run_sweep(
    path: str,
    out_dir: str,
    *,
    scheduler: str | None = None,
    workers: int = 2,
    force: bool = False,
    progress: bool = False,
    repair: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Run or resume a sweep.

    Parameters
    ----------
    path : str
        The sweep file.
    out_dir : str
        Writes points/, results.csv, results.parquet and ensemble.csv; re-running resumes.
    scheduler : str, optional
        None for a local Dask cluster of ``workers`` processes, "serial" for no Dask, or the
        address of an existing scheduler.
    workers : int
        >= 1.
    force : bool
        Start a different (or unreadable) sweep in ``out_dir`` afresh; recompute corrupt points.
    progress : bool
    repair : bool
        Recompute corrupt point files and rewrite an unreadable sweep.json, keeping valid points.
    checks : boresight.jobs.resources.Checks
        The memory check (the largest point, once per local worker) and the time limit (the
        points to run, shared by the workers).

    Returns
    -------
    list of dict
        The table's rows, in sweep order.
    """
    base, base_dir, points = load_sweep(path)
    tasks.check_workers(workers)
    if scheduler != "serial":
        tasks.dask("sweeps")  # before anything is written
    out = io.check_output_path(out_dir, [path, base_dir])
    keys = [point_key(base, base_dir, p) for p in points]
    spec_id = {"sweep": os.path.abspath(path), "points": points, "keys": keys}
    _open_sweep_dir(out, spec_id, force, repair)
    bands = {k: _n_bands(base, base_dir, p) for k, p in zip(keys, points)}
    todo = []
    for p, key in zip(points, keys):
        f = out / "points" / f"{key}.json"
        if not f.exists():
            todo.append((p, key))
            continue
        try:
            read_point(f, key, bands[key])
        except CorruptPointError:
            if not (repair or force):
                raise
            f.unlink()
            todo.append((p, key))
    log.info("sweep: %d points, %d already done", len(points), len(points) - len(todo))
    resources.require(_estimate(base, base_dir, todo, scheduler, workers), checks)
    bar = tqdm(
        total=len(points), initial=len(points) - len(todo), unit="point", disable=not progress
    )

    def finish(overrides, key, rows):
        path = out / "points" / f"{key}.json"
        io.write_json(path, {"overrides": overrides, "key": key, "rows": rows})
        bar.update(1)

    try:
        if todo:
            tasks.run(
                run_point,
                [(base, base_dir, p) for p, _ in todo],
                lambda i, rows: finish(*todo[i], rows),
                scheduler=scheduler,
                workers=workers,
            )
    except KeyboardInterrupt as err:  # the command line's Interrupted, or a notebook's Ctrl-C
        stop = err if isinstance(err, interrupts.Interrupted) else interrupts.Interrupted()
        stop.kept = f"finished points are kept in {out_dir}; re-run to resume"
        raise stop from None
    finally:  # also on Ctrl-C: the table holds every finished point, a re-run adds the rest
        bar.close()
        rows = write_tables(out, points, keys, bands)
    return rows


def _estimate(base, base_dir, todo, scheduler, workers):
    """The sweep's estimate: its largest point in each local process at once, and every point's
    time shared by them (a remote cluster's memory is its own)."""
    each = [
        resources.study_estimate("simulate", parse_study(apply_overrides(base, p), base_dir))
        for p, _ in todo
    ]
    if not each:
        return resources.Estimate("sweep")
    largest = max(each, key=lambda e: e.bytes)
    local = 1 if scheduler == "serial" else workers if scheduler is None else 0
    share = max(local, 1)
    return resources.Estimate(
        "sweep",
        {k: v * local for k, v in largest.parts.items()} if local else {},
        sum(e.seconds for e in each) / share,
        sum(e.samples for e in each),
    )


def write_tables(out: Path, points: list[dict], keys: list[str], bands: dict) -> list[dict]:
    """Assemble the finished points, in sweep order, into results.csv, .parquet and ensemble.csv.

    Parameters
    ----------
    out : pathlib.Path
    points : list of dict
    keys : list of str
    bands : dict
        Point key -> number of bands.

    Returns
    -------
    list of dict
    """
    out = Path(out)
    rows = []
    for i, (p, key) in enumerate(zip(points, keys)):
        f = out / "points" / f"{key}.json"
        if f.exists():
            for r in read_point(f, key, bands[key]):
                rows.append(
                    {
                        "point": i,
                        **{k: json.dumps(v) if isinstance(v, list) else v for k, v in p.items()},
                        **r,
                    }
                )
    if not rows:
        return rows
    columns = _columns(points)
    io.write_csv(out / "results.csv", rows, columns)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq

        with io.atomic_path(out / "results.parquet") as tmp:
            pq.write_table(pa.Table.from_pylist([{c: r[c] for c in columns} for r in rows]), tmp)
    except ImportError:
        pass
    ens = ensemble(rows, list(points[0]))
    if ens:
        io.write_csv(out / "ensemble.csv", ens, list(ens[0]))
    return rows


SEED_KEYS = ("sky.seed", "scan.seed")


def ensemble(rows: list[dict], keys: list[str]) -> list[dict]:
    """Mean and scatter of the residual and delta_r over sky and scan seeds.

    Parameters
    ----------
    rows : list of dict
    keys : list of str
        The swept keys; the seed keys are pooled, the others group.

    Returns
    -------
    list of dict
        One per (other parameters, band); empty when no seed is swept.
    """
    group_keys = [k for k in keys if k not in SEED_KEYS]
    if len(group_keys) == len(keys):
        return []
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in group_keys) + (r["ell_lo"], r["ell_hi"]), []).append(
            r
        )
    out = []
    for key, members in groups.items():
        res = np.array([m["residual_bb"] for m in members])
        dr = np.array([m["delta_r"] for m in members])
        out.append(
            {
                **dict(zip(group_keys, key[:-2])),
                "ell_lo": key[-2],
                "ell_hi": key[-1],
                "n_realisations": len(members),
                "residual_bb_mean": res.mean(),
                "residual_bb_std": res.std(ddof=1) if len(res) > 1 else 0.0,
                "delta_r_mean": dr.mean(),
                "delta_r_std": dr.std(ddof=1) if len(dr) > 1 else 0.0,
            }
        )
    return out
