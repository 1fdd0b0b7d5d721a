"""Focal planes: where each detector pair sits in the field of view, and how it is turned.

A detector's place is SO's and TOAST's projected focal-plane coordinates (xi, eta, gamma): xi and
eta the offset from the boresight, gamma the detector's polarisation orientation, the rotation
``toast.instrument_coords.xieta_to_quat`` builds. A pair is two detectors at one position, B
turned 90 deg from A; pair i's angle in :class:`boresight.instrument.pairs.Instrument` is detector A's
gamma, and its crossing angle is that of the focal plane's "up" axis carried to its position
(:func:`boresight.pointing.detector_pointing`). Differential pointing and the other systematics
stay on top, per pair, as before.

Focal planes come from TOAST 3's own HDF5 file (``Focalplane.save_hdf5``: a table ``focalplane``
with a ``quat`` column in TOAST's (x, y, z, w) order), read with h5py and astropy alone; from a
CSV or TOML table (name, xi_deg, eta_deg, gamma_deg and optionally pol_angle_deg and pair); or
from a preset: TOAST's hexagon (``fake_hexagon_focalplane``), or the paper's pairs on the axis,
the default, which every earlier result assumes.

The partners of a pair are named by a ``pair`` column, TOAST's ``pixel`` column, or by names
that differ in one letter, A and B ("D00A-150", "D00B-150"). Every bad focal plane raises one
:class:`FocalPlaneError` naming the file and the detector.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import validation
from .._util.io import tomllib
from ..constants import DEG
from ..validation import ConfigError

#: a detector's position may sit this far from its partner's [deg] (TOAST's quaternions round
#: trip through xi, eta to 1e-12 rad)
PARTNER_POSITION_TOLERANCE_DEG = 1.0 / 3600
#: partners must be this close to 90 deg apart, modulo 180 deg [deg]; a larger departure is a
#: non-orthogonality, a systematic (``nonortho_deg``), not a layout
ORTHOGONALITY_TOLERANCE_DEG = 1.0
#: quaternions whose norm differs from one by more than this are input mistakes
QUATERNION_NORM_TOLERANCE = 1e-6
#: the widest offset from the boresight a focal plane may hold [deg]: the projection (xi, eta)
#: covers a hemisphere
MAX_RADIUS_DEG = 60.0
TABLE_COLUMNS = ("name", "xi_deg", "eta_deg", "gamma_deg")
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")


class FocalPlaneError(ConfigError):
    """A focal-plane file or table that cannot be used, with the file and detector named."""


@dataclass(frozen=True)
class FocalPlane:
    """Detector pairs and their places in the focal plane, one entry per pair.

    Parameters
    ----------
    names : tuple of str
        Each pair's name.
    detectors : tuple of (str, str)
        The names of each pair's detectors A and B.
    xi_deg, eta_deg : numpy.ndarray, shape (pairs,)
        The pair's offset from the boresight: TOAST/SO's projected coordinates xi, eta (sine-like,
        xi^2 + eta^2 = sin^2 of the distance), given in degrees (xi [rad] x 180 / pi).
    gamma_deg : numpy.ndarray, shape (pairs,)
        Detector A's polarisation orientation gamma [deg]: the pair's angle.
    hn_offset_deg : numpy.ndarray, shape (pairs, 2)
        gamma less the polarisation angle TOAST states (its ``pol_angle``), per detector A and B
        [deg]: what sotodlib's ``Hn`` psi adds to the pair's crossing angle.
    source : str
        The file or preset it came from.
    rotation_centre_deg : tuple of float
        (xi0, eta0) [deg, as xi]: where in the focal plane the boresight rotation turns about
        (sotodlib's ``fp_rot_xi0``, ``fp_rot_eta0`` of its ``sat_v1`` pointing model; SO's
        ``bs_xi0``, ``bs_eta0``); (0, 0), the default, is the focal plane's centre. Off it, a
        boresight angle moves every pair (:meth:`vectors`).
    """

    names: tuple
    detectors: tuple
    xi_deg: np.ndarray
    eta_deg: np.ndarray
    gamma_deg: np.ndarray
    hn_offset_deg: np.ndarray
    source: str = ""
    rotation_centre_deg: tuple = (0.0, 0.0)

    def __post_init__(self):
        n = len(self.names)
        if n == 0:
            raise FocalPlaneError("a focal plane needs one pair or more; it has none")
        if len(self.detectors) != n:
            raise FocalPlaneError(f"focal plane: {len(self.detectors)} detector pairs, {n} names")
        for name, shape in (
            ("xi_deg", (n,)),
            ("eta_deg", (n,)),
            ("gamma_deg", (n,)),
            ("hn_offset_deg", (n, 2)),
        ):
            try:
                values = np.asarray(getattr(self, name), dtype=np.float64)
            except (TypeError, ValueError):
                raise FocalPlaneError(f"focal plane {name}: numbers, one per pair") from None
            if values.shape != shape:
                raise FocalPlaneError(
                    f"focal plane {name}: shape {shape} expected, got {values.shape}"
                )
            if not np.isfinite(values).all():
                raise FocalPlaneError(f"focal plane {name}: NaN or infinite values")
            object.__setattr__(self, name, values)
        if not np.all(np.hypot(self.xi_deg * DEG, self.eta_deg * DEG) < 1):
            raise FocalPlaneError(
                "focal plane: a pair off the boresight's hemisphere (xi^2 + eta^2 >= 1 in sine "
                "units, xi and eta given in degrees as xi [rad] x 180 / pi)"
            )
        try:
            centre = validation.numbers_array(
                "focal plane rotation_centre_deg", self.rotation_centre_deg, -MAX_RADIUS_DEG,
                MAX_RADIUS_DEG,
            )  # fmt: skip
        except (TypeError, ValueError) as err:
            raise FocalPlaneError(str(err)) from None
        if centre.shape != (2,):
            raise FocalPlaneError("focal plane rotation_centre_deg: give (xi0, eta0) [deg]")
        object.__setattr__(self, "rotation_centre_deg", (float(centre[0]), float(centre[1])))

    @property
    def n_pairs(self) -> int:
        return len(self.names)

    @property
    def pair_angles_deg(self) -> tuple:
        """Each pair's angle, detector A's gamma [deg] (``Instrument.pair_angles_deg``)."""
        return tuple(float(g) for g in self.gamma_deg)

    @property
    def radius_deg(self) -> np.ndarray:
        """Each pair's angular distance from the boresight [deg], (pairs,)."""
        return np.degrees(np.arcsin(np.hypot(self.xi_deg * DEG, self.eta_deg * DEG)))

    @property
    def files(self) -> list[str]:
        """The file it was read from, as a list for an output's checks (empty for a preset)."""
        return [self.source] if self.source and Path(self.source).is_file() else []

    @property
    def is_on_axis(self) -> bool:
        """Whether every pair sits on the boresight."""
        return bool(np.all(self.xi_deg == 0) and np.all(self.eta_deg == 0))

    @property
    def centred(self) -> bool:
        """Whether the boresight rotation turns about the focal plane's centre."""
        return self.rotation_centre_deg == (0.0, 0.0)

    def vectors(self, boresight_deg: float = 0.0) -> np.ndarray:
        """Each pair's direction and orientation in the boresight's frame, (pairs, 6): the z and
        x axes of ``xieta_to_quat(xi, eta, 0)`` (TOAST's detector frame at gamma = 0), for
        :func:`boresight.pointing.detector_pointing`; at a boresight angle, turned about the
        rotation centre (:func:`off_centre`)."""
        return off_centre(
            xieta_vectors(self.xi_deg * DEG, self.eta_deg * DEG),
            self.rotation_centre_deg,
            boresight_deg,
        )

    def subset(self, pairs) -> FocalPlane:
        """The focal plane of some of the pairs, in the order given."""
        idx = np.asarray(pairs, dtype=np.int64)
        return FocalPlane(
            names=tuple(self.names[i] for i in idx),
            detectors=tuple(self.detectors[i] for i in idx),
            xi_deg=self.xi_deg[idx],
            eta_deg=self.eta_deg[idx],
            gamma_deg=self.gamma_deg[idx],
            hn_offset_deg=self.hn_offset_deg[idx],
            source=self.source,
            rotation_centre_deg=self.rotation_centre_deg,
        )


def off_centre(vectors: np.ndarray, centre_deg: tuple, boresight_deg: float) -> np.ndarray:
    """Detector vectors (n, 6) at a boresight angle, where the rotation turns about
    ``centre_deg`` = (xi0, eta0) [deg] rather than the boresight.

    sotodlib's ``sat_v1`` model (``coords.pointing_model.model_sat_v1``) writes the rolled
    boresight as Q(az, el) R0 E(roll) R0^-1, R0 = ``rotation_xieta(xi0, eta0)``, and a detector
    at R_d as that times R_d; boresight turns each detector by E(a) about the boresight (its
    boresight angle a is sotodlib's roll, TOAST's rotation). So the vectors become
    E(-a) R0 E(a) R0^-1 v: the same detector seen from the boresight turned by a.

    Parameters
    ----------
    vectors : numpy.ndarray, shape (n, 6)
        :func:`xieta_vectors`' directions and orientations at angle 0.
    centre_deg : tuple of float
    boresight_deg : float

    Returns
    -------
    numpy.ndarray, shape (n, 6)
        ``vectors`` itself where the centre is (0, 0) or the angle 0.
    """
    if tuple(centre_deg) == (0.0, 0.0) or boresight_deg == 0:
        return vectors
    centre = xieta_vectors(np.array([centre_deg[0] * DEG]), np.array([centre_deg[1] * DEG]))[0]
    z, x = centre[:3], centre[3:]
    r0 = np.stack([x, np.cross(z, x), z], axis=1)  # columns: R0's x, y, z axes
    c, s = np.cos(boresight_deg * DEG), np.sin(boresight_deg * DEG)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    m = turn.T @ r0 @ turn @ r0.T
    out = np.empty_like(vectors)
    out[:, :3], out[:, 3:] = vectors[:, :3] @ m.T, vectors[:, 3:] @ m.T
    return out


def xieta_vectors(xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """The direction and orientation of detectors at (xi, eta) with gamma = 0, in the boresight's
    frame: the z and x axes of TOAST's ``xieta_to_quat(xi, eta, 0)``.

    Parameters
    ----------
    xi, eta : numpy.ndarray, shape (n,)
        Projected offsets [rad], xi^2 + eta^2 < 1.

    Returns
    -------
    numpy.ndarray, shape (n, 6)
        Direction (-eta, -xi, cos rho) and orientation (1 - eta^2 / (1 + cos rho),
        -xi eta / (1 + cos rho), eta), with sin rho = ``|(xi, eta)|``: the rotation about the axis
        perpendicular to the offset, which carries the boresight to the detector.
    """
    xi, eta = np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64)
    cos_rho = np.sqrt(1.0 - xi**2 - eta**2)
    return np.stack(
        [-eta, -xi, cos_rho, 1 - eta**2 / (1 + cos_rho), -xi * eta / (1 + cos_rho), eta], axis=-1
    )


def quaternion_matrices(quats: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions in TOAST's (x, y, z, w) order, (n, 3, 3)."""
    x, y, z, w = np.asarray(quats, dtype=np.float64).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quaternion_xieta(quats: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xi, eta, gamma) [rad] of detector quaternions in TOAST's (x, y, z, w) order, (n, 4): the
    inverse of ``toast.instrument_coords.xieta_to_quat``, also on the axis."""
    m = quaternion_matrices(quats)
    direction, orientation = m[:, :, 2], m[:, :, 0]
    xi, eta = -direction[:, 1], -direction[:, 0]
    untwisted = xieta_vectors(xi, eta)[:, 3:]
    gamma = np.arctan2(
        np.einsum("ij,ij->i", np.cross(untwisted, orientation), direction),
        np.einsum("ij,ij->i", untwisted, orientation),
    )
    return xi, eta, gamma


def toast_pol_angles(quats: np.ndarray) -> np.ndarray:
    """The polarisation angle TOAST's ``Focalplane`` gives a detector without a ``pol_angle``
    column [rad]: arctan2(2 w z, w^2 - z^2) modulo pi."""
    q = np.asarray(quats, dtype=np.float64)
    return np.arctan2(2 * q[:, 3] * q[:, 2], q[:, 3] ** 2 - q[:, 2] ** 2) % np.pi


def on_axis(pair_angles_deg=(0.0, 45.0)) -> FocalPlane:
    """Pairs on the boresight at the given angles: the paper's Q and U pairs by default.

    Parameters
    ----------
    pair_angles_deg : sequence of float
        Detector A's angle of each pair [deg].

    Returns
    -------
    FocalPlane
    """
    if isinstance(pair_angles_deg, (str, bytes)) or np.ndim(pair_angles_deg) != 1:
        raise TypeError(f"pair_angles_deg = {pair_angles_deg!r}: a sequence of angles [deg]")
    gamma = np.asarray(pair_angles_deg, dtype=np.float64)
    names = tuple(f"P{i:0{len(str(gamma.size))}d}" for i in range(gamma.size))
    zero = np.zeros(gamma.size)
    return FocalPlane(
        names=names,
        detectors=tuple((f"{n}A", f"{n}B") for n in names),
        xi_deg=zero,
        eta_deg=zero.copy(),
        gamma_deg=gamma,
        hn_offset_deg=np.zeros((gamma.size, 2)),
        source="axis",
    )


#: the largest hexagon built (20,000 pairs is more than any one focal plane's optics tube)
MAX_HEXAGON_PIXELS = 20_000


def _hex_rings(n_pix):
    """Rings of a hexagon of n_pix positions (TOAST's ``hex_nring``)."""
    rings, left = 1, n_pix - 1
    while left - 6 * rings >= 0:
        left -= 6 * rings
        rings += 1
    if left != 0 or n_pix < 1:
        raise FocalPlaneError(
            f"hexagon: {n_pix} pixels is not a hexagonal number (1, 7, 19, 37, 61, ...)"
        )
    return rings


def _ring_step(pix):
    """(ring, sector, step) of hexagon position pix > 0, numbered outward ring by ring."""
    left, ring = pix - 1, 1
    while left - 6 * ring >= 0:
        left -= 6 * ring
        ring += 1
    return ring, left // ring, left % ring


def _hex_column(n_pix, pix):
    """The column of position pix (TOAST's ``hex_xieta_row_col``), whose parity sets its angles."""
    rings = _hex_rings(n_pix)
    if pix == 0:
        return rings - 1
    ring, sector, step = _ring_step(pix)
    start = rings - ring - 1
    return start + (2 * ring - step, ring - step, 0, 0, step, ring + step)[sector]


def hexagon(n_pix: int, width_deg: float) -> FocalPlane:
    """TOAST's hexagonal focal plane (``fake_hexagon_focalplane``): n_pix pixels whose centres
    span ``width_deg`` from vertex to vertex, numbered outward ring by ring, each a pair with A at
    0 deg and B at 90 deg, or at 45 and 135 deg on alternate columns (``hex_gamma_angles_qu``).

    Parameters
    ----------
    n_pix : int
        1, 7, 19, 37, 61, ...
    width_deg : float
        Vertex-to-vertex distance of the outer pixels' centres [deg].

    Returns
    -------
    FocalPlane
    """
    if not 0 <= width_deg < 2 * MAX_RADIUS_DEG:
        raise FocalPlaneError(f"hexagon: width_deg = {width_deg} must be in [0, 120)")
    if not 1 <= n_pix <= MAX_HEXAGON_PIXELS:  # refused before it is built, pixel by pixel
        raise FocalPlaneError(
            f"hexagon: {n_pix} pixels; at most {MAX_HEXAGON_PIXELS} (a focal plane's "
            "per-pair work grows with its pairs: read a larger one from a file)"
        )
    rings = _hex_rings(n_pix)
    spacing = width_deg * DEG / max(2 * rings - 2, 1)
    xi, eta, gamma = np.zeros(n_pix), np.zeros(n_pix), np.zeros(n_pix)
    for pix in range(n_pix):
        gamma[pix] = 45.0 * (_hex_column(n_pix, pix) % 2)
        if pix == 0:
            continue
        ring, sector, step = _ring_step(pix)
        midline = np.sqrt(3) / 2 * ring
        relative = np.arctan2(step - 0.5 * ring, midline)
        angle = sector * np.pi / 3 + np.pi / 6 + relative
        distance = np.sqrt(3) / 2 * spacing * ring / np.cos(relative)
        xi[pix], eta[pix] = np.sin(distance) * np.cos(angle), np.sin(distance) * np.sin(angle)
    names = tuple(f"D{p:0{int(np.log10(n_pix)) + 1}d}" for p in range(n_pix))
    pol = np.stack([gamma, gamma + 90.0], axis=-1)
    offset = pol - pol % 180.0  # TOAST's pol_angle is gamma modulo 180 deg
    return FocalPlane(
        names=names,
        detectors=tuple((f"{n}A", f"{n}B") for n in names),
        xi_deg=np.degrees(xi),
        eta_deg=np.degrees(eta),
        gamma_deg=gamma,
        hn_offset_deg=offset,
        source=f"hexagon:{n_pix}:{width_deg:g}",
    )


def _text(path):
    """A table's text: UTF-8 (a byte-order mark dropped), refusing what a reader would misread:
    binary data, UTF-16 (NUL bytes), gzip or another encoding."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise FocalPlaneError(f"{path}: {err.strerror}") from None
    if data[:2] == b"\x1f\x8b":
        raise FocalPlaneError(f"{path}: gzip-compressed; decompress it first")
    if b"\0" in data:
        raise FocalPlaneError(
            f"{path}: binary (or UTF-16) data; a focal-plane table is UTF-8 text (CSV or TOML)"
        )
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise FocalPlaneError(
            f"{path}: not UTF-8 text (byte {err.start}); save it as UTF-8"
        ) from None


def _table_rows(path):
    """Rows of a CSV or TOML focal-plane table, as dicts of text or numbers."""
    text = _text(path)
    if path.suffix.lower() == ".toml":
        try:
            rows = tomllib.loads(text).get("detector")
        except tomllib.TOMLDecodeError as err:
            raise FocalPlaneError(f"{path}: not valid TOML ({err})") from None
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise FocalPlaneError(f"{path}: expected a [[detector]] table per detector")
        return rows
    lines = [
        line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")
    ]
    return list(csv.DictReader(lines, skipinitialspace=True))


def _file_centre(path):
    """A TOML focal plane's top-level ``rotation_centre_deg = [xi0, eta0]``, else (0, 0)."""
    if path.suffix.lower() != ".toml":
        return (0.0, 0.0)
    centre = tomllib.loads(_text(path)).get("rotation_centre_deg", (0.0, 0.0))
    if not isinstance(centre, (list, tuple)):
        raise FocalPlaneError(f"{path}: rotation_centre_deg: give [xi0, eta0] [deg]")
    return tuple(centre)


def _number(path, name, column, value):
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise FocalPlaneError(
            f"{path}: detector {name}: {column} = {value!r} is not a number"
        ) from None
    if not np.isfinite(out):
        raise FocalPlaneError(f"{path}: detector {name}: {column} = {value!r} is not finite")
    return out


def _read_table(path):
    """Detectors of a CSV/TOML table: names, xi, eta, gamma, pol angle [rad], pair labels."""
    rows = _table_rows(path)
    if not rows:
        raise FocalPlaneError(f"{path}: no detectors")
    for column in TABLE_COLUMNS:
        if column not in rows[0]:
            raise FocalPlaneError(
                f"{path}: missing column {column!r}; a focal-plane table has "
                f"{', '.join(TABLE_COLUMNS)}, and optionally pol_angle_deg and pair"
            )
    names, values, pairs = [], [], []
    for i, row in enumerate(rows):
        name = str(row.get("name") or "").strip()
        if not name:
            raise FocalPlaneError(f"{path}: row {i + 1} has no name")
        columns = ("xi_deg", "eta_deg", "gamma_deg")
        xi, eta, gamma = (_number(path, name, c, row.get(c)) for c in columns)
        pol = row.get("pol_angle_deg")
        pol = gamma if pol in (None, "") else _number(path, name, "pol_angle_deg", pol)
        names.append(name)
        values.append((xi * DEG, eta * DEG, gamma * DEG, pol * DEG))
        pairs.append(str(row["pair"]).strip() if row.get("pair") not in (None, "") else None)
    xi, eta, gamma, pol = np.array(values).T
    return names, xi, eta, gamma, pol, pairs, None


def _find_dataset(handle, name="focalplane"):
    """The path of the first dataset called ``name`` in an HDF5 file."""
    if name in handle:
        return name
    found = []
    handle.visititems(lambda key, obj: found.append(key) if key.split("/")[-1] == name else None)
    return found[0] if found else None


def _read_toast_hdf5(path):
    """Detectors of TOAST 3's focal-plane HDF5 file: names, xi, eta, gamma, pol angle [rad],
    pair labels (TOAST's ``pixel`` column) and the field of view it states [rad]."""
    import h5py
    from astropy import units as u
    from astropy.io.misc.hdf5 import read_table_hdf5

    try:
        with h5py.File(path, "r") as handle:
            where = _find_dataset(handle)
            if where is None:
                raise FocalPlaneError(f"{path}: no 'focalplane' dataset (TOAST's save_hdf5)")
            table = read_table_hdf5(handle, path=where)
    except OSError as err:
        raise FocalPlaneError(f"{path}: not a readable HDF5 file ({err})") from None
    for column in ("name", "quat"):
        if column not in table.colnames:
            raise FocalPlaneError(f"{path}: missing column {column!r} in its focalplane table")
    if len(table) == 0:
        raise FocalPlaneError(f"{path}: its focalplane table has no detectors")
    names = [n.decode() if isinstance(n, bytes) else str(n) for n in table["name"]]
    try:
        quats = np.asarray(table["quat"], dtype=np.float64)
    except (TypeError, ValueError):
        raise FocalPlaneError(f"{path}: column 'quat' must hold numbers") from None
    if quats.ndim != 2 or quats.shape[1] != 4:
        raise FocalPlaneError(f"{path}: column 'quat' must hold 4 numbers per detector")
    for name, q in zip(names, quats):
        if not np.isfinite(q).all():
            raise FocalPlaneError(f"{path}: detector {name}: quat {q.tolist()} is not finite")
        if abs(np.linalg.norm(q) - 1) > QUATERNION_NORM_TOLERANCE:
            raise FocalPlaneError(
                f"{path}: detector {name}: quat {q.tolist()} is not a unit quaternion "
                f"(norm {np.linalg.norm(q):.9g})"
            )
    xi, eta, gamma = quaternion_xieta(quats)
    if "pol_angle" in table.colnames:
        try:
            pol = np.asarray(u.Quantity(table["pol_angle"], u.rad).value, dtype=np.float64)
        except (TypeError, ValueError, u.UnitsError) as err:
            raise FocalPlaneError(f"{path}: column 'pol_angle' must be an angle ({err})") from None
        for name, angle in zip(names, pol):
            if not np.isfinite(angle):
                raise FocalPlaneError(f"{path}: detector {name}: pol_angle {angle} is not finite")
    else:
        pol = toast_pol_angles(quats)
    pairs = None
    if "pixel" in table.colnames:
        pairs = [p.decode() if isinstance(p, bytes) else str(p) for p in table["pixel"]]
    fov = table.meta.get("field_of_view")
    try:
        fov = None if fov is None else float(u.Quantity(fov, u.rad).value)
    except (TypeError, ValueError, u.UnitsError) as err:
        raise FocalPlaneError(f"{path}: field_of_view must be an angle ({err})") from None
    return names, xi, eta, gamma, pol, pairs, fov


def _partner_key(name):
    """The pair a detector named with one A or B belongs to and which one it is: the name with
    its last A or B taken out, and that letter; (None, None) for a name without either."""
    match = re.match(r"^(.*)([AB])([^AB]*)$", name)
    if match is None:
        return None, None
    return match.group(1) + match.group(3), match.group(2)


def _pairs(path, names, pairs):
    """Indices (a, b) of each pair's detectors, and its name, in first-appearance order."""
    groups = {}
    for i, name in enumerate(names):
        if pairs is not None and pairs[i] is not None:
            key, letter = pairs[i], None
        else:
            key, letter = _partner_key(name)
            if key is None:
                raise FocalPlaneError(
                    f"{path}: detector {name}: no partner: its name has no A or B, and no "
                    "'pair' column names its pair"
                )
        groups.setdefault(key, []).append((letter, i))
    out = []
    for key, members in groups.items():
        if len(members) != 2:
            who = ", ".join(names[i] for _, i in members)
            what = "no partner" if len(members) == 1 else f"{len(members)} detectors in one pair"
            raise FocalPlaneError(f"{path}: detector {who}: {what}")
        (la, a), (lb, b) = members
        if la is not None and la == lb:  # PA1 and P1A: one pair's name, both detector A
            raise FocalPlaneError(
                f"{path}: detectors {names[a]}, {names[b]}: both are detector {la} of pair {key}"
            )
        if la == "B" and lb == "A":
            a, b = b, a
        out.append((a, b, key))
    return out


def read_focalplane(path: str | Path) -> FocalPlane:
    """A focal plane from a file: TOAST 3's HDF5 (``.h5``, ``.hdf5``) or a CSV/TOML table (a
    TOML one may give its rotation centre, ``rotation_centre_deg = [xi0, eta0]``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    FocalPlane

    Raises
    ------
    FocalPlaneError
        A missing file or column, a non-unit quaternion, NaN, a duplicate name, a detector
        without a partner, partners apart or not at right angles, or an offset beyond the field
        of view the file states (or beyond :data:`MAX_RADIUS_DEG`).
    """
    path = Path(path)
    if not path.exists():
        raise FocalPlaneError(f"focal plane {str(path)!r}: no such file")
    if not path.is_file():  # a FIFO would block the reader
        raise FocalPlaneError(
            f"focal plane {str(path)!r}: not a regular file (a directory, FIFO or device)"
        )
    if path.suffix.lower() in HDF5_SUFFIXES:
        names, xi, eta, gamma, pol, pairs, fov = _read_toast_hdf5(path)
    else:
        names, xi, eta, gamma, pol, pairs, fov = _read_table(path)
    seen = set()
    for name in names:
        if name in seen:
            raise FocalPlaneError(f"{path}: detector {name}: the name appears twice")
        seen.add(name)
    radius = np.degrees(np.arcsin(np.minimum(np.hypot(xi, eta), 1.0)))
    limit = MAX_RADIUS_DEG if fov is None else min(MAX_RADIUS_DEG, 0.5 * np.degrees(fov))
    for name, r, x, e in zip(names, radius, xi, eta):
        if not np.hypot(x, e) < 1 or r > limit:
            where = "the field of view the file states" if fov is not None else "the limit"
            raise FocalPlaneError(
                f"{path}: detector {name}: offset {r:.4g} deg from the boresight is beyond "
                f"{where} ({limit:.4g} deg)"
            )
    chosen = _pairs(path, names, pairs)
    a = np.array([c[0] for c in chosen])
    b = np.array([c[1] for c in chosen])
    for i, j in zip(a, b):
        apart = np.degrees(np.hypot(xi[i] - xi[j], eta[i] - eta[j]))
        if apart > PARTNER_POSITION_TOLERANCE_DEG:
            raise FocalPlaneError(
                f"{path}: detector {names[j]}: {apart * 3600:.3g} arcsec from its partner "
                f"{names[i]}; a pair's detectors share one position"
            )
        turn = np.degrees(gamma[j] - gamma[i]) % 180.0
        if abs(turn - 90.0) > ORTHOGONALITY_TOLERANCE_DEG:
            raise FocalPlaneError(
                f"{path}: detector {names[j]}: {turn:.4g} deg from its partner {names[i]}, "
                f"not 90 deg (within {ORTHOGONALITY_TOLERANCE_DEG} deg)"
            )
    return FocalPlane(
        names=tuple(c[2] for c in chosen),
        detectors=tuple((names[i], names[j]) for i, j in zip(a, b)),
        xi_deg=np.degrees(0.5 * (xi[a] + xi[b])),
        eta_deg=np.degrees(0.5 * (eta[a] + eta[b])),
        gamma_deg=np.degrees(gamma[a]),
        hn_offset_deg=np.degrees(np.stack([gamma[a] - pol[a], gamma[b] - pol[b]], axis=-1)),
        source=str(path),
        rotation_centre_deg=_file_centre(path),
    )


def load_focalplane(spec: str) -> FocalPlane:
    """A focal plane from a file or a preset name: ``hexagon:N:WIDTH_DEG`` (TOAST's hexagon of N
    pixels, WIDTH_DEG wide) or ``axis`` (the paper's Q and U pairs on the boresight).

    Parameters
    ----------
    spec : str

    Returns
    -------
    FocalPlane
    """
    if spec == "axis":
        return on_axis()
    if spec.startswith("hexagon:"):
        parts = spec.split(":")
        try:
            if len(parts) != 3:
                raise ValueError(spec)
            n_pix, width = int(parts[1]), float(parts[2])
        except ValueError:
            raise FocalPlaneError(
                f"focal plane {spec!r}: a hexagon is 'hexagon:N:WIDTH_DEG', e.g. 'hexagon:37:35'"
            ) from None
        return hexagon(n_pix, width)
    return read_focalplane(spec)


def focalplane_of_table(table: dict, base: str | Path) -> FocalPlane:
    """The focal plane of an ``[instrument]`` table with a ``focalplane`` key (a study's or a
    budget's): a file beside it (relative to ``base``), else a preset name
    (:func:`load_focalplane`). It gives the pairs and their angles, so the table holds nothing
    else but ``rotation_centre_deg`` = [xi0, eta0], the point the boresight turns about
    (:attr:`FocalPlane.rotation_centre_deg`).

    Parameters
    ----------
    table : dict
    base : str or pathlib.Path
        The directory of the file the table came from.

    Returns
    -------
    FocalPlane
    """
    spec = table["focalplane"]
    if not isinstance(spec, str):
        raise FocalPlaneError("[instrument] focalplane must be a file or a preset name")
    others = sorted(set(table) - {"focalplane", "rotation_centre_deg"})
    if others:
        raise FocalPlaneError(
            f"[instrument] focalplane gives the pairs and their angles: remove {others}"
        )
    beside = Path(base) / spec
    focal = load_focalplane(str(beside) if beside.is_file() else spec)
    if "rotation_centre_deg" not in table:
        return focal
    centre = table["rotation_centre_deg"]
    if not isinstance(centre, (list, tuple)):
        raise FocalPlaneError("[instrument] rotation_centre_deg: give [xi0, eta0] [deg]")
    return replace(focal, rotation_centre_deg=tuple(centre))
