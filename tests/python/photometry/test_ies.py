"""IES LM-63 photometry (hirad.photometry.ies): real files against their published lumen totals,
closed-form profiles written as IES files here, the axes, every symmetry, types A and B, the
version-dependent fields, and every kind of bad file.

Oracles: the lumen totals stated for the files of ../shared/data/ies (Photometric Toolbox's
totals in rab/ies_summary_reference_lumens.md; the luminaire flux in the BEGA files' [LAMP]
line; the manufacturer's [_ABSOLUTELUMENS] keyword), and closed forms: the flux of
I0 cos^n(gamma) over the lower hemisphere is 2 pi I0 / (n + 1); its beam (50 %) and field
(10 %) angles are 2 acos(0.5^(1/n)) and 2 acos(0.1^(1/n)).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from hirad.photometry import (
    IesError,
    IesWarning,
    angles_to_direction,
    beam_field_angles,
    candela,
    direction_to_angles,
    ies_command,
    lumens,
    parse_ies,
    peak_candela,
    read_ies,
)

# an IesWarning nobody asked for fails the test (the files written here are clean)
pytestmark = pytest.mark.filterwarnings("error::hirad.photometry.ies.IesWarning")

SHARED_IES = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "ies"


# ----------------------------------------------------------------------------- writing files


def fmt(values, per_line=10):
    vals = [f"{v:.10g}" for v in np.asarray(values, dtype=float).ravel()]
    return "\n".join(" ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line))


def ies_text(v, h, cand, *, tag="IESNA:LM-63-2002", ptype=1, lumens_per_lamp=-1, n_lamps=1,
             mult=1.0, units=2, dims=(0, 0, 0), ballast=1.0, second=1.0, watts=10.0,
             tilt="NONE", keywords=("[TEST] hirad test", "[MANUFAC] hirad"), eol="\n"):
    """An IES file: ``cand`` is (len(v), len(h)) (vertical x horizontal)."""
    cand = np.asarray(cand, dtype=float)
    assert cand.shape == (len(v), len(h))
    lines = ([tag] if tag else []) + list(keywords) + [f"TILT={tilt}"]
    lines.append(f"{n_lamps} {lumens_per_lamp:g} {mult:g} {len(v)} {len(h)} {ptype} {units} "
                 f"{dims[0]:g} {dims[1]:g} {dims[2]:g}")
    lines.append(f"{ballast:g} {second:.5f} {watts:g}")
    lines.append(fmt(v))
    lines.append(fmt(h))
    for j in range(len(h)):
        lines.append(fmt(cand[:, j]))
    return eol.join(lines) + eol


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_bytes(text.encode("latin-1") if isinstance(text, str) else text)
    return p


def cos_n_grid(n, step=0.5, i0=1000.0, h=(0.0,), vmax=180.0):
    v = np.arange(0.0, vmax + step / 2, step)
    col = i0 * np.where(v <= 90.0, np.cos(np.radians(np.minimum(v, 90.0))) ** n, 0.0)
    return v, np.array(h, dtype=float), np.repeat(col[:, None], len(h), axis=1)


# ----------------------------------------------------------------------------- shared files


def _reference_lumens():
    """{relative path: (reference lm, tolerance, where the reference is stated)}"""
    refs = {}
    table = SHARED_IES / "rab" / "ies_summary_reference_lumens.md"
    text = table.read_text(encoding="utf-8")
    header = None
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None and "file name" in cells:
            header = cells
            continue
        if header and cells and re.match(r"^\d+\.ies$", cells[0], re.IGNORECASE):
            col = header.index("Photometric Toolbox lumen")
            refs[f"rab/{cells[0].split('.')[0]}.IES"] = (
                float(cells[col]), 0.005, "Photometric Toolbox total (ies_summary_reference_lumens.md)")
    for f in sorted((SHARED_IES / "ieslibrary").glob("*.ies")):
        m = re.search(r"^\[LAMP\]\s*([\d.]+)\s*lm", f.read_text(encoding="utf-8", errors="replace"),
                      re.MULTILINE)
        if m:  # BEGA files: absolute photometry, the [LAMP] line states the luminaire flux
            refs[f"ieslibrary/{f.name}"] = (float(m.group(1)), 0.005,
                                            "luminaire flux in the BEGA [LAMP] line")
    # the manufacturer's keyword; an integer, and the lab's total from its own (denser)
    # measurement: this type-B file's published angle set integrates 0.52 % above it with
    # every interpolant tried (the mid-cell zonal sum is 1.0 % above), so 1 % is allowed here
    refs["rab/flood_2.1.IES"] = (10601.0, 0.01, "[_ABSOLUTELUMENS] keyword of the file")
    return refs


def _shared_files():
    if not SHARED_IES.is_dir():
        return []
    return sorted(p.relative_to(SHARED_IES).as_posix() for p in SHARED_IES.glob("*/*")
                  if p.suffix.lower() == ".ies")


@pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent: the shared IES "
                    "data set (../shared/data/ies beside the project) is not on this machine")
def test_every_shared_file_is_covered():
    files = _shared_files()
    assert len(files) == 19, files
    refs = _reference_lumens()
    without = [f for f in files if f not in refs]
    # the four files that state no luminaire flux anywhere (checked by the cross-check below)
    assert sorted(without) == sorted([
        "ieslibrary/108b32f07d6d38a7a6528a6d307440df.ies",
        "ieslibrary/1a936937a49c63374e6d4fbed9252b29.ies",
        "ieslibrary/1aec5958092c236d005093ca27ebe378.ies",
        "rab/flood_2.2.ies"])


@pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent: the shared IES "
                    "data set (../shared/data/ies beside the project) is not on this machine")
@pytest.mark.parametrize("name", sorted(_reference_lumens()) if SHARED_IES.is_dir() else [])
def test_shared_file_lumens_match_reference(name):
    ref, tol, where = _reference_lumens()[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IesWarning)
        p = read_ies(SHARED_IES / name)
    got = lumens(p)
    assert abs(got / ref - 1.0) <= tol, f"{name}: {got:.2f} lm, reference {ref} ({where})"


def _midcell_zonal(p):
    """Independent coarse zonal sum: every tabulated value times the solid angle of its cell
    (cells bounded half-way between neighbouring angles), over the symmetry-expanded grid."""
    v = p.vertical_angles
    h = p.horizontal_angles
    t = p.candela
    if p.photometric_type == "C":
        if len(h) == 1:
            h, t = np.array([0.0, 360.0]), np.repeat(t, 2, axis=1)
        if h[-1] == 90:
            h, t = np.concatenate([h, 180 - h[-2::-1]]), np.concatenate([t, t[:, -2::-1]], 1)
        if h[-1] == 180:
            h, t = np.concatenate([h, 360 - h[-2::-1]]), np.concatenate([t, t[:, -2::-1]], 1)
        if h[0] == 90 and h[-1] == 270:  # mirrored about the C90-C270 plane: I(C) = I(180 - C)
            h = np.concatenate([h, 180 - h[-2:0:-1] + 360])
            t = np.concatenate([t, t[:, -2:0:-1]], 1)
        edges_v = np.concatenate([[v[0]], (v[1:] + v[:-1]) / 2, [v[-1]]])
        dcos = np.cos(np.radians(edges_v[:-1])) - np.cos(np.radians(edges_v[1:]))
        hh = np.concatenate([h[:-1]]) if h[-1] == 360 else h
        tt = t[:, :len(hh)]
        ext = np.concatenate([[hh[-1] - 360], hh, [hh[0] + 360]])
        dc = np.radians((ext[2:] - ext[:-2]) / 2)
        return float(dcos @ tt @ dc)
    if h[0] == 0:
        h, t = np.concatenate([-h[:0:-1], h]), np.concatenate([t[:, :0:-1], t], 1)
    eh = np.radians(np.concatenate([[h[0]], (h[1:] + h[:-1]) / 2, [h[-1]]]))
    ev = np.radians(np.concatenate([[v[0]], (v[1:] + v[:-1]) / 2, [v[-1]]]))
    return float(np.diff(ev) @ t @ np.diff(np.sin(eh)))


@pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent")
@pytest.mark.parametrize("name", _shared_files())
def test_shared_file_lumens_agree_with_coarse_zonal_sum(name):
    """No published total for four files: there the interpolant's flux is held to an
    independent mid-cell zonal sum (the method behind the BEGA totals), 1 % (type B grids of
    5-10 degree steps differ by 0.5 % between the two methods)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IesWarning)
        p = read_ies(SHARED_IES / name)
    got, zonal = lumens(p), _midcell_zonal(p)
    tol = 0.005 if p.photometric_type == "C" else 0.01
    assert abs(got / zonal - 1) <= tol, f"{name}: interpolant {got:.2f}, zonal sum {zonal:.2f}"


@pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent")
def test_shared_latin1_file_is_read_with_a_warning():
    with pytest.warns(IesWarning, match=r"4\.IES: line 5: byte 0xA0 is not UTF-8"):
        p = read_ies(SHARED_IES / "rab" / "4.IES")
    assert p.version == 2002 and p.photometric_type == "C"
    assert "BAYLED78W" in p.keywords["LUMCAT"][0]


@pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent")
def test_shared_files_facts():
    """Header facts read from the real files (values as printed in them)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IesWarning)
        bega = read_ies(SHARED_IES / "ieslibrary" / "007cfb11e343e2f42e3b476be4ab684e.ies")
        cooper = read_ies(SHARED_IES / "ieslibrary" / "1aec5958092c236d005093ca27ebe378.ies")
        r4 = read_ies(SHARED_IES / "rab" / "4.IES")
        r1 = read_ies(SHARED_IES / "rab" / "1.IES")
        fl = read_ies(SHARED_IES / "rab" / "flood_2.2.ies")
        bega90 = read_ies(SHARED_IES / "ieslibrary" / "02a7562c650498ebb301153dbbf59207.ies")
    # 1995, circular opening of 0.080 m written as (-0.080, 0, 0) in metres
    assert bega.version == 1995 and bega.opening.shape == "circular"
    assert bega.opening.width_m == pytest.approx(0.080) and bega.absolute
    assert bega.symmetry.startswith("axial")
    # one number per line, relative photometry of 3500 lamp lumens
    assert cooper.lamp_lumens == 3500 and not cooper.absolute
    assert cooper.input_watts == 92.0 and len(cooper.vertical_angles) == 73
    assert 0 < cooper.efficiency() < 1
    # 2002 vertical cylinder in feet: (-1.041667, -1.041667, 0.114833) ft
    assert r4.opening.shape == "vertical cylinder"
    assert r4.opening.width_m == pytest.approx(1.041667 * 0.3048)
    assert r4.opening.height_m == pytest.approx(0.114833 * 0.3048)
    assert r4.multiplier == pytest.approx(0.9687)
    assert np.allclose(r4.candela, r4.candela_raw * 0.9687)
    assert r1.opening.shape == "rectangular with luminous sides"
    assert r1.symmetry.startswith("quadrilateral")
    assert fl.photometric_type == "B" and fl.symmetry.startswith("none")
    assert bega90.symmetry.startswith("bilateral about C90-C270")


# ----------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("n", [1, 2, 5, 20])
def test_cos_n_flux(tmp_path, n):
    i0 = 1000.0
    v, h, cand = cos_n_grid(n, step=0.5, i0=i0)
    p = read_ies(write(tmp_path, f"cos{n}.ies", ies_text(v, h, cand)))
    expected = 2 * math.pi * i0 / (n + 1)
    assert lumens(p) == pytest.approx(expected, rel=1e-3)
    # the same profile on a 0-90 range with several planes (quadrilateral form)
    v2, h2, c2 = cos_n_grid(n, step=1.0, i0=i0, h=(0, 30, 60, 90), vmax=90.0)
    p2 = read_ies(write(tmp_path, f"cos{n}_q.ies", ies_text(v2, h2, c2)))
    assert lumens(p2) == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize("n", [2, 5, 20])
def test_cos_n_beam_field_and_peak(tmp_path, n):
    v, h, cand = cos_n_grid(n, step=0.5)
    p = read_ies(write(tmp_path, "b.ies", ies_text(v, h, cand)))
    beam = 2 * math.degrees(math.acos(0.5 ** (1 / n)))
    fld = 2 * math.degrees(math.acos(0.1 ** (1 / n)))
    for a in beam_field_angles(p):
        assert a.beam_deg == pytest.approx(beam, abs=0.1), a
        assert a.field_deg == pytest.approx(fld, abs=0.1), a
        assert a.peak_cd == pytest.approx(1000.0)
    pk, g, _ = peak_candela(p)
    assert pk == pytest.approx(1000.0) and g == 0.0


def test_interpolation_is_smooth_exact_at_nodes_and_wraps(tmp_path):
    """Exact at the tabulated points; continuous across C = 360 and through the pole."""
    v = np.arange(0, 181, 10.0)
    h = np.arange(0, 360, 30.0)  # 0..330: wrap from 330 to 360 = 0
    g, c = np.meshgrid(v, h, indexing="ij")
    f = 100 + 50 * np.cos(np.radians(g)) + 20 * np.sin(np.radians(g)) * np.cos(np.radians(c - 40))
    p = read_ies(write(tmp_path, "s.ies", ies_text(v, h, f)))
    assert np.allclose(candela(p, g[1:-1], c[1:-1]), f[1:-1], rtol=0, atol=1e-6)  # 10 digits written
    eps = 1e-6
    assert candela(p, 45, 360 - eps) == pytest.approx(candela(p, 45, eps), abs=1e-3)
    assert candela(p, 45, -30) == pytest.approx(candela(p, 45, 330), abs=1e-9)
    # through the pole: the value at gamma -> 0 is one value for every C
    near = candela(p, 1e-7, np.arange(0, 360, 7.0))
    assert np.ptp(near) < 1e-3
    # C1: the slope across the pole in the C40-C220 plane (where the C term is largest) is
    # continuous: left and right one-sided differences agree
    d = 0.01
    left = (candela(p, d, 220) - candela(p, 2 * d, 220)) / d
    right = (candela(p, d, 40) - candela(p, 0, 40)) / d
    assert left == pytest.approx(right, rel=0.05)
    # smooth: no overshoot above the largest tabulated value, none below zero
    gg, cc = np.meshgrid(np.linspace(0, 180, 181), np.linspace(0, 360, 361), indexing="ij")
    dense = candela(p, gg, cc)
    assert dense.max() <= f.max() + 1e-9 and dense.min() >= 0


# ----------------------------------------------------------------------------- axes


def test_axes_profile_lit_around_c90_lights_plus_y(tmp_path):
    v = np.arange(0, 181, 5.0)
    h = np.arange(0, 361, 10.0)
    g, c = np.meshgrid(v, h, indexing="ij")
    cand = np.where((np.abs(c - 90) <= 20) & (np.abs(g - 90) <= 30), 500.0, 0.0)
    p = read_ies(write(tmp_path, "c90.ies", ies_text(v, h, cand)))
    assert p.intensity([0, 1, 0]) == pytest.approx(500.0)
    assert p.intensity([0, 2.5, -0.2]) > 400  # +Y, a little below the horizon
    for d in ([0, -1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, -1], [0, 0, 1]):
        assert p.intensity(d) == 0.0, d
    # the frame itself: nadir -Z is gamma 0, +X is C0, +Y is C90
    gam, cc = direction_to_angles(np.array([[0, 0, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
    assert np.allclose(gam, [0, 90, 90, 180]) and np.allclose(cc[1:3], [0, 90])
    assert np.allclose(angles_to_direction(90, 90), [0, 1, 0], atol=1e-12)
    assert np.allclose(angles_to_direction(30, 0), [0.5, 0, -math.cos(math.radians(30))])


def test_axes_downlight_lights_minus_z(tmp_path):
    v, h, cand = cos_n_grid(4, step=1.0)
    p = read_ies(write(tmp_path, "down.ies", ies_text(v, h, cand)))
    assert p.intensity([0, 0, -1]) == pytest.approx(1000.0)
    assert p.intensity([0, 0, 1]) == 0.0
    assert p.intensity([[1, 0, -1], [0, -1, -1]]) == pytest.approx([250.0, 250.0], rel=1e-3)


# ----------------------------------------------------------------------------- symmetries


def _directions(k=200, seed=3):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(k, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _c_file(tmp_path, name, func, h, step=2.5, n_plane_step=None):
    v = np.arange(0, 180 + step / 2, step)
    g, c = np.meshgrid(v, np.asarray(h, float), indexing="ij")
    return read_ies(write(tmp_path, name, ies_text(v, np.asarray(h, float), func(g, c))))


def g_of(gam):
    return 1000.0 * np.where(gam <= 90, np.cos(np.radians(np.minimum(gam, 90))) ** 3, 0.0)


def test_every_symmetry_of_an_axial_distribution_agrees(tmp_path):
    f = lambda g, c: g_of(g) + 0 * c  # noqa: E731
    forms = {
        "0": [0.0],
        "0-90": np.arange(0, 91, 15.0),
        "0-180": np.arange(0, 181, 15.0),
        "0-360": np.arange(0, 361, 15.0),
        "90-270": np.arange(90, 271, 15.0),
    }
    ps = {k: _c_file(tmp_path, f"ax{k}.ies", f, h) for k, h in forms.items()}
    d = _directions()
    ref_i = ps["0"].intensity(d)
    expected_flux = 2 * math.pi * 1000.0 / 4
    for k, p in ps.items():
        assert lumens(p) == pytest.approx(expected_flux, rel=1e-3), k
        assert np.allclose(p.intensity(d), ref_i, rtol=1e-7, atol=1e-6), k
    assert ps["90-270"].symmetry.startswith("bilateral about C90-C270")
    assert ps["0-90"].symmetry.startswith("quadrilateral")


def test_quadrilateral_bilateral_and_full_forms_agree(tmp_path):
    # symmetric about both planes: I(C) = I(-C) = I(180 - C)
    f = lambda g, c: g_of(g) * (1 + 0.5 * np.sin(np.radians(g)) ** 2  # noqa: E731
                                * np.cos(np.radians(2 * c)))
    q = _c_file(tmp_path, "q.ies", f, np.arange(0, 91, 5.0))
    b = _c_file(tmp_path, "b.ies", f, np.arange(0, 181, 5.0))
    n = _c_file(tmp_path, "n.ies", f, np.arange(0, 361, 5.0))
    m = _c_file(tmp_path, "m.ies", f, np.arange(90, 271, 5.0))
    d = _directions()
    for p in (b, n, m):
        assert np.allclose(p.intensity(d), q.intensity(d), rtol=1e-7, atol=1e-6), p.symmetry
        assert lumens(p) == pytest.approx(lumens(q), rel=1e-7)
    assert lumens(q) == pytest.approx(2 * math.pi * 1000 / 4, rel=2e-3)  # cos 2C integrates to 0


def test_bilateral_0_180_mirrors_about_the_c0_plane(tmp_path):
    # I(C) = I(-C); the C term vanishes at the pole, as it must for one direction there
    f = lambda g, c: g_of(g) * (1 + 0.6 * np.sin(np.radians(g)) * np.cos(np.radians(c)))  # noqa: E731
    b = _c_file(tmp_path, "b.ies", f, np.arange(0, 181, 5.0))
    n = _c_file(tmp_path, "n.ies", f, np.arange(0, 360, 5.0))
    d = _directions()
    assert np.allclose(b.intensity(d), n.intensity(d), rtol=1e-7, atol=1e-6)
    # C0 side is the bright side: +X
    r = 0.6 * math.sin(math.radians(45))
    assert b.intensity([1, 0, -1]) / b.intensity([-1, 0, -1]) == pytest.approx((1 + r) / (1 - r),
                                                                             rel=1e-6)


def test_bilateral_90_270_mirrors_about_the_c90_plane_not_rotated(tmp_path):
    # I(C) = I(180 - C)
    f = lambda g, c: g_of(g) * (1 + 0.6 * np.sin(np.radians(g)) * np.sin(np.radians(c)))  # noqa: E731
    m = _c_file(tmp_path, "m.ies", f, np.arange(90, 271, 5.0))
    n = _c_file(tmp_path, "n.ies", f, np.arange(0, 360, 5.0))
    d = _directions()
    assert np.allclose(m.intensity(d), n.intensity(d), rtol=1e-7, atol=1e-6)
    r = 0.6 * math.sin(math.radians(45))
    assert m.intensity([0, 1, -1]) / m.intensity([0, -1, -1]) == pytest.approx((1 + r) / (1 - r),
                                                                             rel=1e-6)
    assert m.intensity([1, 0, -1]) == pytest.approx(m.intensity([-1, 0, -1]), rel=1e-9)
    assert lumens(m) == pytest.approx(2 * math.pi * 1000 / 4, rel=2e-3)


def test_360_column_wraps_and_vertical_ranges(tmp_path):
    f = lambda g, c: g_of(g) * (1 + 0.3 * np.sin(np.radians(g))  # noqa: E731
                                * np.cos(np.radians(c - 30)))
    a = _c_file(tmp_path, "a.ies", f, np.arange(0, 361, 10.0))
    b = _c_file(tmp_path, "b.ies", f, np.arange(0, 351, 10.0))
    d = _directions()
    assert np.allclose(a.intensity(d), b.intensity(d), rtol=1e-7, atol=1e-6)
    # vertical 90-180: an uplight; nothing below the horizon
    v = np.arange(90, 181, 1.0)
    up = 800 * np.cos(np.radians(180 - v)) ** 2
    p = read_ies(write(tmp_path, "up.ies", ies_text(v, [0.0], up[:, None])))
    assert p.intensity([0, 0, 1]) == pytest.approx(800)
    assert p.intensity([0, 0.2, -1]) == 0.0
    assert lumens(p) == pytest.approx(2 * math.pi * 800 / 3, rel=1e-3)


# ----------------------------------------------------------------------------- types A and B


def rot_x(a):
    """Rotation matrices (..., 3, 3) about X by angles a (radians)."""
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


NADIR = np.array([0.0, 0.0, -1.0])


def dir_type_b(h_deg, v_deg):
    """LM-63 type B: H is the latitude towards the (horizontal) polar axis, V the plane's
    tilt about that axis. hirad frame: polar axis Y, +V turns the photometric axis (-Z)
    toward +X: first tilt by H toward +Y (about X), then turn about Y."""
    return rot_y(-np.radians(v_deg)) @ rot_x(np.radians(h_deg)) @ NADIR


def dir_type_a(h_deg, v_deg):
    """LM-63 type A: V is the latitude towards the (vertical) polar axis, H the plane's turn
    about it. hirad frame: polar axis X, +H turns -Z toward +Y."""
    return rot_x(np.radians(h_deg)) @ rot_y(-np.radians(v_deg)) @ NADIR


def spot(axis, half_deg=50.0, i0=1000.0):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    c0 = math.cos(math.radians(half_deg))

    def f(d):
        d = np.asarray(d, float)
        mu = d @ a
        return i0 * np.clip((mu - c0) / (1 - c0), 0, None) ** 2

    flux = 2 * math.pi * i0 * (1 - c0) / 3  # closed form of the cap integral
    return f, flux


def test_dir_helpers_match_the_documented_formulas():
    for h, v in ((10, 0), (0, 10), (30, -40), (-70, 25)):
        hr, vr = math.radians(h), math.radians(v)
        assert np.allclose(dir_type_b(h, v), [math.cos(hr) * math.sin(vr), math.sin(hr),
                                              -math.cos(hr) * math.cos(vr)])
        assert np.allclose(dir_type_a(h, v), [math.sin(vr), math.cos(vr) * math.sin(hr),
                                              -math.cos(vr) * math.cos(hr)])


@pytest.mark.parametrize("axis,lateral", [((0.3, -0.25, -1.0), False),
                                          ((math.sin(0.35), 0.0, -math.cos(0.35)), True)])
def test_types_a_b_c_give_the_same_intensities(tmp_path, axis, lateral):
    f, flux = spot(axis)
    # type C, fine grid
    vc = np.arange(0, 180.5, 1.0)
    hc = np.arange(0, 360.5, 2.0)
    G, Cc = np.meshgrid(vc, hc, indexing="ij")
    pc = read_ies(write(tmp_path, "c.ies", ies_text(vc, hc, f(angles_to_direction(G, Cc)))))
    vb = np.arange(-90, 90.5, 1.0)
    hb = np.arange(0 if lateral else -90, 90.5, 1.0)
    VV, HH = np.meshgrid(vb, hb, indexing="ij")  # rows V, columns H
    tb = f(dir_type_b(HH, VV))
    ta = f(dir_type_a(HH, VV))
    pb = read_ies(write(tmp_path, "b.ies", ies_text(vb, hb, tb, ptype=2)))
    pa = read_ies(write(tmp_path, "a.ies", ies_text(vb, hb, ta, ptype=3)))
    assert pb.photometric_type == "B" and pa.photometric_type == "A"
    assert pb.symmetry.startswith("laterally symmetric" if lateral else "none")
    d = _directions(400)
    d = d[d @ (np.asarray(axis) / np.linalg.norm(axis)) > math.cos(math.radians(45))]
    assert len(d) > 20
    truth = f(d)
    for p in (pc, pb, pa):
        got = p.intensity(d)
        assert np.max(np.abs(got - truth)) < 0.01 * 1000.0, p.photometric_type
        assert lumens(p) == pytest.approx(flux, rel=3e-3), p.photometric_type
    # away from the spot every type gives nothing (e.g. straight up, and sideways)
    for p in (pc, pb, pa):
        assert p.intensity([0, 0, 1]) == 0.0 and p.intensity([-1, 0, 0.2]) == 0.0
    # peak direction is the spot axis in every type
    for p in (pc, pb, pa):
        _, g, c = peak_candela(p)
        pd = angles_to_direction(g, c)
        assert math.degrees(math.acos(min(1, pd @ (np.asarray(axis) / np.linalg.norm(axis))))) < 1.5


# ----------------------------------------------------------------------------- versions


def _simple(tmp_path, name, **kw):
    v, h, cand = cos_n_grid(1, step=1.0, i0=1000.0)
    return read_ies(write(tmp_path, name, ies_text(v, h, cand, **kw)))


def test_version_tags_and_second_field(tmp_path):
    base = 2 * math.pi * 1000 / 2
    # 1986: no tag; free label lines; the second field is the ballast-lamp photometric factor
    p86 = _simple(tmp_path, "86.ies", tag=None, keywords=("A 1986 FILE, FREE LABEL",),
                  ballast=0.9, second=0.8)
    assert p86.version == 1986 and p86.ballast_lamp_factor == pytest.approx(0.8)
    assert lumens(p86) == pytest.approx(base * 0.9 * 0.8, rel=1e-3)
    assert lumens(p86, ballast=False) == pytest.approx(base, rel=1e-3)
    p91 = _simple(tmp_path, "91.ies", tag="IESNA91", second=0.5)
    assert p91.version == 1991 and lumens(p91) == pytest.approx(base * 0.5, rel=1e-3)
    # 1995/2002: "future use" is no factor (a warning when it is not 1)
    with pytest.warns(IesWarning, match=r"95\.ies: line 6: the 'future use' field"):
        p95 = _simple(tmp_path, "95.ies", tag="IESNA:LM-63-1995", second=0.5)
    assert p95.version == 1995 and p95.ballast_lamp_factor == 1.0
    assert lumens(p95) == pytest.approx(base, rel=1e-3)
    p02 = _simple(tmp_path, "02.ies", ballast=0.95)
    assert p02.version == 2002 and lumens(p02) == pytest.approx(base * 0.95, rel=1e-3)
    # 2019: file generation type, decoded, never a factor
    p19 = _simple(tmp_path, "19.ies", tag="IES:LM-63-2019", second=1.10000)
    assert p19.version == 2019 and p19.file_generation == "test at an accredited lab"
    assert lumens(p19) == pytest.approx(base, rel=1e-3)


def test_relative_photometry_multiplier_and_units(tmp_path):
    p = _simple(tmp_path, "rel.ies", lumens_per_lamp=1500, n_lamps=2, mult=2.5, units=1,
                dims=(-0.5, -0.5, 0), ballast=0.8)
    assert not p.absolute and p.lamp_lumens == 3000
    assert np.allclose(p.candela, 2.5 * p.candela_raw)
    assert lumens(p) == pytest.approx(0.8 * 2.5 * math.pi * 1000, rel=1e-3)
    assert p.intensity([0, 0, -1]) == pytest.approx(0.8 * 2.5 * 1000)
    assert p.intensity([0, 0, -1], ballast=False) == pytest.approx(2.5 * 1000)
    # light output ratio: the optics' share of the rated lamp flux, without the ballast factor
    assert p.efficiency() == pytest.approx(2.5 * math.pi * 1000 / 3000, rel=1e-3)
    assert p.opening.shape == "circular" and p.opening.width_m == pytest.approx(0.1524)


@pytest.mark.parametrize("tag,dims,shape", [
    ("IESNA:LM-63-2002", (0, 0, 0), "point"),
    ("IESNA:LM-63-2002", (0.6, 1.2, 0), "rectangular"),
    ("IESNA:LM-63-2002", (0.6, 1.2, 0.1), "rectangular with luminous sides"),
    ("IESNA:LM-63-2002", (-0.2, -0.2, 0), "circular"),
    ("IESNA:LM-63-2002", (-0.2, -0.3, 0), "ellipse"),
    ("IESNA:LM-63-2002", (-0.2, -0.2, 0.3), "vertical cylinder"),
    ("IESNA:LM-63-2002", (-0.2, -0.2, -0.2), "sphere"),
    ("IESNA:LM-63-2002", (-0.2, -0.3, -0.4), "ellipsoidal spheroid"),
    ("IESNA:LM-63-2002", (-0.1, 1.2, -0.1), "horizontal cylinder along photometric horizontal"),
    ("IESNA:LM-63-2002", (1.2, -0.1, -0.1),
     "horizontal cylinder perpendicular to photometric horizontal"),
    ("IESNA:LM-63-2002", (-0.3, 0, -0.3), "vertical circle facing photometric horizontal"),
    ("IES:LM-63-2019", (-0.2, -0.2, 0), "circular"),
    ("IESNA:LM-63-1995", (-0.2, 0, 0), "circular"),
    ("IESNA:LM-63-1995", (-0.2, 0, -0.2), "sphere"),
    ("IESNA:LM-63-1995", (-0.2, 0, 0.3), "vertical cylinder"),
    ("IESNA:LM-63-1995", (0, 1.2, -0.1), "horizontal cylinder along photometric horizontal"),
    ("IESNA91", (-0.2, 0, 0), "circular"),
    ("IESNA91", (-0.2, 0.4, 0), "ellipse"),
])
def test_opening_shapes(tmp_path, tag, dims, shape):
    p = _simple(tmp_path, "o.ies", tag=tag, dims=dims)
    assert p.opening.shape == shape
    assert (p.opening.width_m, p.opening.length_m, p.opening.height_m) == pytest.approx(
        tuple(abs(x) for x in dims))


def test_tilt_include_is_read(tmp_path):
    v, h, cand = cos_n_grid(1, step=1.0)
    text = ies_text(v, h, cand, tilt="INCLUDE")
    text = text.replace("TILT=INCLUDE\n", "TILT=INCLUDE\n1\n3\n0 45 90\n1.0 0.95\n0.9\n")
    p = read_ies(write(tmp_path, "tilt.ies", text))
    assert p.tilt_mode == "INCLUDE" and p.tilt.geometry == 1
    assert p.tilt.factor(45) == pytest.approx(0.95) and p.tilt.factor(67.5) == pytest.approx(0.925)
    assert lumens(p) == pytest.approx(math.pi * 1000, rel=1e-3)


# ----------------------------------------------------------------------------- bad files


def good_text(**kw):
    v = np.array([0.0, 30, 60, 90])
    h = np.array([0.0, 90])
    cand = np.array([[100.0, 100], [80, 70], [40, 30], [0, 0]])
    return ies_text(v, h, cand, **kw)


# line layout of good_text: 1 tag, 2-3 keywords, 4 TILT, 5 header, 6 ballast line,
# 7 vertical angles, 8 horizontal angles, 9 candela at C0, 10 candela at C90


def _bad(tmp_path, text, name="bad.ies"):
    path = write(tmp_path, name, text)
    with pytest.raises(IesError) as e:
        read_ies(path)
    assert str(path) in str(e.value)
    return e.value


def test_good_text_layout_is_what_the_bad_cases_assume(tmp_path):
    lines = good_text().splitlines()
    assert lines[3] == "TILT=NONE" and lines[6].startswith("0 30 60 90") and lines[9] == "100 70 30 0"
    p = read_ies(write(tmp_path, "good.ies", good_text()))
    assert p.symmetry.startswith("quadrilateral")


def test_bad_missing_lines(tmp_path):
    lines = good_text().splitlines()
    e = _bad(tmp_path, "\n".join(lines[:-1]) + "\n")
    assert e.line == 9 and "while reading the candela values for horizontal angle 90" in str(e)
    e = _bad(tmp_path, "\n".join(lines[:3]) + "\n")
    assert "no TILT= line" in str(e)
    e = _bad(tmp_path, "\n".join(lines[:5]) + "\n")
    assert e.line == 5 and "ballast factor" in str(e)
    e = _bad(tmp_path, "")
    assert "empty" in str(e)


def test_bad_non_numeric_tokens(tmp_path):
    e = _bad(tmp_path, good_text().replace("100 80 40 0", "100 80 4O 0"))
    assert e.line == 9 and "'4O' is not a number" in str(e)
    e = _bad(tmp_path, good_text().replace("0 30 60 90", "0 30 nan 90"))
    assert e.line == 7 and "'nan' is not a number" in str(e)
    e = _bad(tmp_path, good_text().replace("1 -1 1 4 2 1 2", "1 -1 1 4.5 2 1 2"))
    assert e.line == 5 and "whole number" in str(e)


def test_bad_wrong_counts(tmp_path):
    # header says 5 vertical angles, the file has 4: the first horizontal angle is read as
    # the fifth vertical angle and the angles stop increasing
    e = _bad(tmp_path, good_text().replace("1 -1 1 4 2 1 2", "1 -1 1 5 2 1 2"))
    assert e.line == 8 and "vertical angles must increase" in str(e)
    assert "line 5 declares 5 vertical and 2 horizontal angles" in str(e)
    # too few values declared: the rest is left over (a warning; the file is usable)
    with pytest.warns(IesWarning, match=r"extra\.ies: line 11: 2 value\(s\) after the candela"):
        p = read_ies(write(tmp_path, "extra.ies", good_text() + "5 6\n"))
    assert p.candela.shape == (4, 2)
    e = _bad(tmp_path, good_text().replace("1 -1 1 4 2 1 2", "1 -1 1 1 2 1 2"))
    assert e.line == 5 and "at least 2" in str(e)


def test_bad_tilt_file_name(tmp_path):
    e = _bad(tmp_path, good_text(tilt="lamp_tilt.tlt"))
    assert e.line == 4 and "lamp_tilt.tlt" in str(e) and "not supported" in str(e)


def test_bad_angles_not_monotone(tmp_path):
    e = _bad(tmp_path, good_text().replace("0 30 60 90", "0 60 30 90"))
    assert e.line == 7 and "vertical angles must increase: 30 follows 60" in str(e)
    e = _bad(tmp_path, good_text().replace("\n0 90\n", "\n90 0\n"))
    assert e.line == 8 and "horizontal angles must increase" in str(e)
    e = _bad(tmp_path, good_text().replace("\n0 90\n", "\n0 120\n"))
    assert e.line == 8 and "no LM-63 symmetry" in str(e)
    e = _bad(tmp_path, good_text().replace("0 30 60 90", "0 30 60 190"))
    assert e.line == 7 and "0..180" in str(e)


def test_bad_negative_candela(tmp_path):
    e = _bad(tmp_path, good_text().replace("100 70 30 0", "100 70 -30 0"))
    assert e.line == 10 and "negative candela -30 at vertical 60, horizontal 90" in str(e)


def test_bad_codes(tmp_path):
    e = _bad(tmp_path, good_text(ptype=4))
    assert e.line == 5 and "photometric type" in str(e)
    e = _bad(tmp_path, good_text(units=3))
    assert e.line == 5 and "units type" in str(e)
    e = _bad(tmp_path, good_text(mult=0))
    assert e.line == 5 and "multiplier" in str(e)
    e = _bad(tmp_path, good_text(tilt="INCLUDE").replace("TILT=INCLUDE\n", "TILT=INCLUDE\n7\n"))
    assert e.line == 5 and "geometry must be 1, 2 or 3" in str(e)


def test_latin1_byte_is_a_warning(tmp_path):
    text = good_text(keywords=("[TEST] hirad", "[LUMINAIRE] 30\xb0 spot"))
    path = write(tmp_path, "latin.ies", text.encode("latin-1"))
    with pytest.warns(IesWarning, match=r"latin\.ies: line 3: byte 0xB0 is not UTF-8"):
        p = read_ies(path)
    assert p.keywords["LUMINAIRE"] == ["30\xb0 spot"]
    # UTF-8 is read as it is, without a warning
    path = write(tmp_path, "utf8.ies", text.encode("utf-8"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", IesWarning)
        assert read_ies(path).keywords["LUMINAIRE"] == ["30\xb0 spot"]


@pytest.mark.parametrize("eol", ["\r\n", "\r"])
def test_crlf_and_cr_line_ends_read_like_lf(tmp_path, eol):
    ref = read_ies(write(tmp_path, "lf.ies", good_text()))
    with warnings.catch_warnings():
        warnings.simplefilter("error", IesWarning)
        p = read_ies(write(tmp_path, "crlf.ies", good_text(eol=eol)))
    assert np.array_equal(p.candela, ref.candela) and lumens(p) == lumens(ref)
    # and errors still name the right line
    e = _bad(tmp_path, good_text(eol=eol).replace("100 70 30 0", "100 70 -30 0"))
    assert e.line == 10


def test_unreadable_file_names_it(tmp_path):
    with pytest.raises(IesError, match="nope.ies: cannot read the file"):
        read_ies(tmp_path / "nope.ies")
    e = _bad(tmp_path, b"IESNA:LM-63-2002\n\x00\x01")
    assert "NUL" in str(e)


def test_parse_from_string_names_the_given_path():
    with pytest.raises(IesError, match=r"^fixture\.ies: line 7"):
        parse_ies(good_text().replace("0 30 60 90", "0 30 30 90"), path="fixture.ies")


# ----------------------------------------------------------------------------- the command


def test_ies_command_report_and_plot(tmp_path):
    v, h, cand = cos_n_grid(5, step=0.5)
    path = write(tmp_path, "cos5.ies", ies_text(v, h, cand, tag="IESNA:LM-63-1995"))
    pytest.importorskip("matplotlib")
    out = tmp_path / "polar.png"
    text = ies_command(path, plot=out)
    flux = 2 * math.pi * 1000 / 6
    m = re.search(r"lumens \(zonal integration[^:]*\): ([\d.]+) lm", text)
    assert m and float(m.group(1)) == pytest.approx(flux, rel=1e-3)
    assert "version: LM-63-1995" in text and "photometric type: C" in text
    assert "symmetry: axial" in text and "peak candela: 1000.0 cd" in text
    beam = 2 * math.degrees(math.acos(0.5 ** (1 / 5)))
    m = re.search(r"C0-C180 plane: .* beam angle \(50 %\) ([\d.]+) deg, field angle \(10 %\) "
                  r"([\d.]+) deg", text)
    assert m and float(m.group(1)) == pytest.approx(beam, abs=0.1)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 5000


def test_ies_command_bad_file_raises(tmp_path):
    path = write(tmp_path, "bad.ies", good_text(tilt="x.tlt"))
    with pytest.raises(IesError, match=r"bad\.ies: line 4: TILT=x\.tlt"):
        ies_command(path)


def test_lumens_is_the_flux_of_the_evaluated_intensity(tmp_path):
    """lumens() integrates exactly the surface intensity() evaluates: held against a plain
    midpoint sum of candela() over a 0.25 degree grid of directions."""
    v = np.arange(0, 181, 7.5)
    h = np.arange(0, 360, 20.0)
    g, c = np.meshgrid(v, h, indexing="ij")
    f = 300 * (1.2 + np.cos(np.radians(g))) * (1 + 0.4 * np.sin(np.radians(g))
                                              * np.cos(np.radians(c - 70)))
    p = read_ies(write(tmp_path, "s.ies", ies_text(v, h, f)))
    step = 0.25
    gm = np.arange(step / 2, 180, step)
    cm = np.arange(step / 2, 360, step)
    G, Cc = np.meshgrid(gm, cm, indexing="ij")
    brute = float((candela(p, G, Cc) * np.sin(np.radians(G))[:, :1]).sum()
                  * math.radians(step) ** 2)
    assert lumens(p) == pytest.approx(brute, rel=2e-5)
    # and the closed form of the tabulated function, to the interpolation error
    assert lumens(p) == pytest.approx(300 * 1.2 * 4 * math.pi, rel=2e-3)
