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

import copy
import hashlib
import itertools
import json
import os
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from . import coupling, engine, io, masks, predict, rbias, sky, spectra
from .config import ConfigError, parse_study, tomllib
from .cosmology import load_spectra

POINT_COLUMNS = (
    "ell_lo",
    "ell_hi",
    "residual_bb",
    "residual_auto_bb",
    "residual_cross_bb",
    "predicted_bb",
    "delta_r",
    "predicted_delta_r",
)


def load_sweep(path):
    """Read a sweep file -> (base raw config, base directory, list of override dicts)."""
    if not os.path.exists(path):
        raise ConfigError(f"sweep file not found: {path}")
    with open(path, "rb") as f:
        try:
            spec = tomllib.load(f)
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"{path} is not valid TOML: {err}") from None
    unknown = set(spec) - {"base", "mode", "parameters"}
    if unknown:
        raise ConfigError(f"unknown sweep keys {sorted(unknown)}; allowed: base, mode, parameters")
    base_dir = os.path.dirname(os.path.abspath(path))
    if "base" not in spec:
        raise ConfigError("sweep needs base = 'STUDY.toml'")
    base_path = os.path.join(base_dir, spec["base"])
    if not os.path.exists(base_path):
        raise ConfigError(f"base: file not found: {base_path}")
    with open(base_path, "rb") as f:
        base = tomllib.load(f)
    points = expand(spec.get("parameters", {}), spec.get("mode", "grid"))
    for overrides in points:  # validate every point before any work
        parse_study(apply_overrides(base, overrides), os.path.dirname(base_path))
    return base, os.path.dirname(base_path), points


def expand(parameters, mode):
    """Override dicts for a grid (cartesian product) or a list (zip) of parameter values."""
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


def apply_overrides(base, overrides):
    """A copy of the raw config with dotted keys set (pbr_angle_deg: rotations [0, angle])."""
    raw = copy.deepcopy(base)
    for key, value in overrides.items():
        if key == "pbr_angle_deg":
            section, name = "scan", "rotations_deg"
            value = [0.0] if value in (0, None) else [0.0, float(value)]
        elif key.count(".") == 1:
            section, name = key.split(".")
        else:
            raise ConfigError(f"sweep parameter {key!r}: use 'section.key' or 'pbr_angle_deg'")
        raw.setdefault(section, {})[name] = value
    return raw


def point_key(overrides):
    """A stable file name for a point: hash of its overrides."""
    text = json.dumps(overrides, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


_COUPLING = {}  #: this worker's last coupling matrices, keyed by (mask digest, lmax)


def _coupling_matrices(mask, lmax, nthreads):
    """Coupling matrices of the mask, reused while a worker's points share mask and lmax (most
    sweeps vary the scan or the systematics; at lmax 4000 a set costs ~10 s on 16 cores)."""
    key = (hashlib.sha256(np.ascontiguousarray(mask).tobytes()).hexdigest(), lmax)
    if key not in _COUPLING:
        _COUPLING.clear()
        _COUPLING[key] = coupling.coupling_matrices(mask, lmax, nthreads)
    return _COUPLING[key]


def run_point(base, base_dir, overrides):
    """Simulate one point; returns its rows (one per ell band). Pure: a task for any worker."""
    study = parse_study(apply_overrides(base, overrides), base_dir)
    nthreads, lmax = study.run["nthreads"], study.output["lmax"]
    the_sky = sky.make_sky(study.sky, nthreads=nthreads)
    mask = masks.from_config(study.mask, the_sky.nside)
    kw = dict(
        pixels=mask > 0,
        evaluation=study.run["evaluation"],
        backend=study.run["backend"],
        chunk_pixels=study.run["chunk_pixels"],
        nthreads=nthreads,
    )
    ref = engine.simulate(the_sky, study.scan, study.instrument, **kw)
    sim = engine.simulate(the_sky, study.scan, study.instrument, study.systematics, **kw)
    cross, auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax, nthreads)
    theory = load_spectra()
    cp = _coupling_matrices(mask, lmax, nthreads)
    h, _ = engine.scan_moments(study.scan, the_sky.nside, pixels=mask > 0, nthreads=nthreads)
    try:
        pred = predict.residual_pseudo_bb(
            h,
            mask,
            cp,
            study.systematics,
            theory,
            study.sky.fwhm_arcmin,
            study.instrument,
            field_cl=predict.local_cl(the_sky, mask, lmax, nthreads),
        )
    except ValueError:  # prediction needs the Q/U pair layout
        pred = np.full(lmax + 1, np.nan)
    template = rbias.tensor_template(cp, theory, study.sky.fwhm_arcmin, the_sky.nside)
    total = cross + auto
    dr, dr_pred = rbias.delta_r(total, template), rbias.delta_r(pred, template)
    edges = spectra.log_bins(study.output["lmin"], lmax, study.output["n_bands"])
    binned = spectra.bin_spectrum(np.array([total, auto, cross, pred]), edges)[1]
    return [
        dict(
            ell_lo=int(lo),
            ell_hi=int(hi) - 1,
            residual_bb=b[0],
            residual_auto_bb=b[1],
            residual_cross_bb=b[2],
            predicted_bb=b[3],
            delta_r=dr,
            predicted_delta_r=dr_pred,
        )
        for lo, hi, b in zip(edges[:-1], edges[1:], binned.T)
    ]


def _columns(points):
    return ["point"] + list(points[0]) + list(POINT_COLUMNS)


def _point_file(out, overrides):
    return Path(out) / "points" / f"{point_key(overrides)}.json"


def run_sweep(path, out_dir, scheduler=None, workers=2, force=False, log=print, progress=False):
    """Run (or resume) a sweep; writes points/, results.csv, results.parquet, ensemble.csv.

    scheduler: None for a local Dask cluster of ``workers`` processes, "serial" for no Dask, or
    the address of an existing Dask scheduler. Returns the table as a list of rows.
    """
    base, base_dir, points = load_sweep(path)
    out = Path(out_dir)
    spec_id = {"sweep": os.path.abspath(path), "points": points}
    marker = out / "sweep.json"
    if out.exists() and any(out.iterdir()):
        if not marker.exists() or json.loads(marker.read_text())["points"] != points:
            if not force:
                raise FileExistsError(f"{out} holds another sweep or other files; use --force")
            import shutil

            shutil.rmtree(out)
    (out / "points").mkdir(parents=True, exist_ok=True)
    for stale in (out / "points").glob(".*"):  # temp files of a write that was killed
        stale.unlink()
    io.write_json(marker, spec_id)
    todo = [p for p in points if not _point_file(out, p).exists()]
    log(f"sweep: {len(points)} points, {len(points) - len(todo)} already done")
    bar = tqdm(
        total=len(points), initial=len(points) - len(todo), unit="point", disable=not progress
    )

    def finish(overrides, rows):
        io.write_json(_point_file(out, overrides), {"overrides": overrides, "rows": rows})
        bar.update(1)

    try:
        if scheduler == "serial":
            for p in todo:
                finish(p, run_point(base, base_dir, p))
        elif todo:
            _run_dask(todo, base, base_dir, scheduler, workers, finish)
    finally:  # also on Ctrl-C: the table holds every finished point, a re-run adds the rest
        bar.close()
        rows = write_tables(out, points)
    return rows


def _run_dask(todo, base, base_dir, scheduler, workers, finish):
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError as err:
        raise ImportError("sweeps on Dask need: pip install 'boresight[dask]'") from err
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        )
    client = Client(cluster if cluster is not None else scheduler)
    try:
        futures = {client.submit(run_point, base, base_dir, p, pure=False): p for p in todo}
        for fut in as_completed(futures):
            finish(futures[fut], fut.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def write_tables(out, points):
    """Assemble finished points (in sweep order) into results.csv, .parquet and ensemble.csv."""
    out = Path(out)
    rows = []
    for i, p in enumerate(points):
        f = _point_file(out, p)
        if f.exists():
            for r in json.loads(f.read_text())["rows"]:
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


def ensemble(rows, keys):
    """Mean and scatter of the residual over sky/scan seeds, per other parameters and band."""
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


def continuum_figure(rows, path_stem):
    """Leaked-power suppression and |delta r| against rotation angle, with the h_n prediction,
    when the sweep varies pbr_angle_deg (skipped otherwise; seeds are pooled)."""
    if not rows or "pbr_angle_deg" not in rows[0]:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def band_sum(angle, col):
        return sum(r[col] for r in rows if r["pbr_angle_deg"] == angle)

    angles = sorted({r["pbr_angle_deg"] for r in rows})
    if 0 not in angles:
        return
    measured = [band_sum(a, "residual_auto_bb") / band_sum(0, "residual_auto_bb") for a in angles]
    closed = [band_sum(a, "predicted_bb") / band_sum(0, "predicted_bb") for a in angles]

    def first(angle, col):
        return next(r[col] for r in rows if r["pbr_angle_deg"] == angle)

    fig, (ax, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    ax.semilogy(angles, measured, "o", label="simulation (leaked power)")
    ax.semilogy(angles, closed, "k--", label="h_n prediction")
    ax.set_xlabel("boresight rotation angle [deg]")
    ax.set_ylabel("residual power / no rotation")
    ax.legend()
    ax_r.semilogy(angles, [abs(first(a, "delta_r")) for a in angles], "o", label="simulation")
    ax_r.semilogy(
        angles, [abs(first(a, "predicted_delta_r")) for a in angles], "k--", label="h_n prediction"
    )
    ax_r.set_xlabel("boresight rotation angle [deg]")
    ax_r.set_ylabel(rf"$|\Delta r|$ ({rbias.R_RANGE[0]} <= ell <= {rbias.R_RANGE[1]})")
    ax_r.legend()
    fig.tight_layout()
    fig.savefig(f"{path_stem}.png", dpi=110)
    plt.close(fig)
