"""Tests of hbeo.data.procedural: determinism, validity, variety, frame conventions."""
import collections

import numpy as np
import pytest
from scipy import ndimage

from hbeo.conventions import CLASSES
from hbeo.data.procedural import VARIANTS, generate

ALL_VARIANTS = [(c, v) for c in CLASSES for v in VARIANTS[c]]

#: Plausible range of the longest bounding-box side per class, metres.
LONGEST = {"bathtub": (1.3, 2.2), "bed": (1.8, 2.6), "chair": (0.6, 1.3), "desk": (0.9, 2.0),
           "dresser": (0.8, 1.9), "monitor": (0.3, 0.9), "night_stand": (0.35, 0.85),
           "sofa": (1.2, 2.7), "table": (0.55, 2.2), "toilet": (0.5, 1.2)}


def first_hit(mesh, axis, point, from_above=True):
    """Coordinate along ``axis`` where a ray parallel to it first meets the mesh, or nan.

    The ray passes through ``point`` (the two other coordinates, in increasing
    axis order) and comes from +inf (from_above) or -inf.
    """
    tri = mesh.vertices[mesh.faces]
    others = [a for a in range(3) if a != axis]
    p = tri[:, :, others]
    e1, e2, d = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], np.asarray(point, float) - p[:, 0]
    den = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(den) > 1e-15
    den = np.where(ok, den, 1.0)
    u = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / den
    v = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / den
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
    if not hit.any():
        return np.nan
    a = tri[:, :, axis]
    t = a[:, 0] + u * (a[:, 1] - a[:, 0]) + v * (a[:, 2] - a[:, 0])
    return float(t[hit].max() if from_above else t[hit].min())


def top_mean(mesh, axis, band=0.02):
    """Mean coordinate along ``axis`` of the vertices within ``band`` of the top."""
    v = mesh.vertices
    return v[v[:, 2] > v[:, 2].max() - band, axis].mean()


# ---------------------------------------------------------------------------- determinism

def test_same_arguments_give_identical_meshes():
    for cls in CLASSES:
        a, b = generate(cls, "train", 3, seed=5), generate(cls, "train", 3, seed=5)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert a.metadata == b.metadata



#: sha256 (first 16 hex digits) of the packed 30^3 grid of ``generate(cls, "test", 1, seed=2)``: the geometry
#: is pinned, so moving the builders between modules must leave it bit for bit, and a change of shape shows
#: here (and needs ``procedural.VERSION`` bumped: it keys the cached grids)
GRID_SHA = {"bathtub": "7800d576ee12e54c", "bed": "689c01e2c15dfb56", "chair": "f092e314af1f4a45",
            "desk": "66717c96769cf3c4", "dresser": "dccd1232e941d588", "monitor": "661619018f118d15",
            "night_stand": "e062ac9c742ccab8", "sofa": "417fa9086bad634f", "table": "c965bb52c568cf84",
            "toilet": "84eaeb544da83bd2"}


def test_generated_grids_are_pinned():
    import hashlib

    from hbeo.data import procedural
    from hbeo.data.voxel import voxelize
    assert procedural.VERSION == 1 and procedural.__all__ == ["VARIANTS", "VERSION", "generate"]
    got = {cls: hashlib.sha256(np.packbits(voxelize(generate(cls, "test", 1, seed=2))).tobytes()).hexdigest()[:16]
           for cls in CLASSES}
    assert got == GRID_SHA, {c: got[c] for c in CLASSES if got[c] != GRID_SHA[c]}

@pytest.mark.parametrize("cls", CLASSES)
def test_different_arguments_give_different_meshes(cls):
    ref = generate(cls, "train", 0)
    for other in (generate(cls, "train", 1), generate(cls, "test", 0), generate(cls, "train", 0, seed=1)):
        assert other.vertices.shape != ref.vertices.shape or not np.allclose(other.vertices, ref.vertices)


def test_forced_variant_and_metadata():
    m = generate("chair", "test", 2, variant="arms/pedestal/slanted")
    assert m.metadata["variant"] == "chair/arms/pedestal/slanted"
    assert m.metadata["class"] == "chair"
    assert m.metadata["split"] == "test" and m.metadata["index"] == 2
    drawn = generate("chair", "test", 2)
    assert drawn.metadata["variant"].split("/")[1:] in [v.split("/") for v in VARIANTS["chair"]]


# ---------------------------------------------------------------------------- validity

@pytest.mark.parametrize("cls,variant", ALL_VARIANTS)
def test_every_variant_is_valid(cls, variant):
    for index in range(4):
        m = generate(cls, "train", index, variant=variant)
        v = m.vertices
        assert len(m.faces) >= 12 and np.isfinite(v).all()
        assert 12 <= len(m.faces) <= 5000
        assert abs(v[:, 2].min()) < 1e-9
        lo, hi = v.min(0), v.max(0)
        assert np.all(np.abs((lo + hi)[:2] / 2) < 1e-9)
        lo_len, hi_len = LONGEST[cls]
        assert lo_len <= m.extents.max() <= hi_len, (variant, m.extents)
        assert m.extents.min() > 0.02
        # parts are closed and outward-wound, so the concatenation is too
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0
        assert m.metadata["variant"] == f"{cls}/{variant}"


# ---------------------------------------------------------------------------- variety

@pytest.mark.parametrize("cls", CLASSES)
def test_variety_within_class(cls):
    meshes = [generate(cls, "train", i) for i in range(40)]
    variants = collections.Counter(m.metadata["variant"] for m in meshes)
    assert len(variants) >= 2
    ext = np.array([m.extents for m in meshes])
    cv = ext.std(0) / ext.mean(0)
    assert np.all(cv > 0.04), cv
    assert len({round(float(e), 6) for e in ext[:, 2]}) == 40


def test_every_variant_occurs():
    for cls in CLASSES:
        seen = {generate(cls, "train", i).metadata["variant"] for i in range(120)}
        assert seen == {f"{cls}/{v}" for v in VARIANTS[cls]}, cls


# ---------------------------------------------------------------------------- frames

def test_chair_back_toward_plus_y():
    for i in range(30):
        m = generate("chair", "train", i)
        assert top_mean(m, 1, band=0.05) > 0, m.metadata["variant"]


def test_slanted_chair_back_leans_back():
    for i in range(10):
        straight = generate("chair", "train", i, variant="noarms/legs/straight")
        slanted = generate("chair", "train", i, variant="noarms/legs/slanted")
        lean = [top_mean(m, 1, 0.05) - m.vertices[:, 1].min() for m in (straight, slanted)]
        assert lean[1] > lean[0] + 0.02


def test_bed_headboard_toward_plus_y_and_long_axis_y():
    for i in range(20):
        m = generate("bed", "train", i)
        assert m.extents[1] > m.extents[0]
        if "headboard" in m.metadata["variant"]:
            assert top_mean(m, 1) > 0


def test_toilet_tank_toward_plus_y():
    for i in range(30):
        m = generate("toilet", "train", i)
        assert top_mean(m, 1, band=0.05) > 0, m.metadata["variant"]
        assert m.extents[1] > m.extents[0]


def test_sofa_back_toward_plus_x():
    for i in range(30):
        m = generate("sofa", "train", i)
        assert top_mean(m, 0) > 0.1 * m.extents[0], m.metadata["variant"]
        assert top_mean(m, 1) == pytest.approx(0.0, abs=0.25 * m.extents[1])


def test_long_axes():
    for i in range(20):
        assert generate("bathtub", "train", i).extents[1] > 1.4 * generate("bathtub", "train", i).extents[0]
        desk = generate("desk", "train", i)
        assert desk.extents[0] > desk.extents[1]
        table = generate("table", "train", i, variant="rect/legs")
        assert table.extents[0] >= table.extents[1] - 1e-9


def test_storage_fronts_face_minus_y():
    """Drawer fronts and handles add geometry on the -y side."""
    for cls, variant in [("dresser", None), ("night_stand", "drawers"), ("desk", "drawers_both_sides")]:
        for i in range(10):
            m = generate(cls, "train", i, variant=variant)
            assert m.vertices[:, 1].mean() < 0, (cls, m.metadata["variant"])


def test_flat_monitor_is_thin_panel_facing_y():
    for i in range(20):
        m = generate("monitor", "train", i)
        if m.metadata["variant"] == "monitor/crt":
            continue
        v = m.vertices
        upper = v[v[:, 2] > 0.5 * v[:, 2].max()]
        assert np.ptp(upper[:, 1]) < 0.35 * np.ptp(upper[:, 0])


# ---------------------------------------------------------------------------- open basins

@pytest.mark.parametrize("variant", VARIANTS["bathtub"])
def test_bathtub_basin_is_open(variant):
    for i in range(5):
        m = generate("bathtub", "train", i, variant=variant)
        rim = first_hit(m, 2, (0.45 * m.extents[0], 0.0))   # on the long wall
        floor = first_hit(m, 2, (0.0, 0.0))                   # down the middle
        assert floor < 0.55 * rim, (variant, floor, rim)
        assert floor < 0.3


def test_bathtub_basin_survives_cavity_filling():
    """Surface voxels + filling of closed cavities leave the basin empty."""
    for variant in VARIANTS["bathtub"]:
        m = generate("bathtub", "train", 1, variant=variant)
        pitch = m.extents.max() / 30
        vox = m.voxelized(pitch)
        grid = np.pad(vox.matrix, 1)
        filled = ndimage.binary_fill_holes(grid)
        i, j, _ = np.asarray(vox.points_to_indices(np.zeros((1, 3))))[0] + 1
        column = filled[i, j]
        k_rim = np.nonzero(grid[i, :, :].any(axis=0))[0].max()
        empty = ~column[: k_rim + 1]
        assert empty.sum() >= 0.4 * (k_rim + 1), variant


@pytest.mark.parametrize("variant", VARIANTS["toilet"])
def test_toilet_bowl_open_unless_lid_down(variant):
    for i in range(5):
        m = generate("toilet", "train", i, variant=variant)
        lo = m.vertices[:, 1].min()
        hits = np.array([first_hit(m, 2, (0.0, y)) for y in np.linspace(lo + 0.02, 0.0, 25)])
        hits = hits[np.isfinite(hits)]
        depth = hits.max() - hits.min()
        if variant == "seat/lid_down":
            assert depth < 0.03
        else:
            assert depth > 0.08


def test_desk_has_knee_hole_dresser_does_not():
    for i in range(15):
        desk = generate("desk", "train", i)
        y = first_hit(desk, 1, (0.0, 0.35), from_above=False)   # ray from the front at knee height
        assert np.isnan(y) or y > 0, desk.metadata["variant"]
        dresser = generate("dresser", "train", i)
        assert first_hit(dresser, 1, (0.0, 0.35), from_above=False) < -0.3 * dresser.extents[1]


# ---------------------------------------------------------------------------- confusable classes

def test_desk_dresser_night_stand_are_close_but_distinct():
    ext = {c: np.array([generate(c, "train", i).extents for i in range(60)])
           for c in ("desk", "dresser", "night_stand")}

    def overlap(a, b, axis):
        return min(a[:, axis].max(), b[:, axis].max()) - max(a[:, axis].min(), b[:, axis].min())

    d, r, n = ext["desk"], ext["dresser"], ext["night_stand"]
    for axis in range(3):                                  # size ranges overlap on every axis
        assert overlap(d, r, axis) > 0
    assert overlap(r, n, 2) > 0 and overlap(r, n, 1) > 0
    assert overlap(d, n, 1) > 0
    w_over_h = {c: (e[:, 0] / e[:, 2]).mean() for c, e in ext.items()}
    assert w_over_h["desk"] > w_over_h["dresser"] + 0.25   # desks are wide and low
    assert w_over_h["dresser"] > w_over_h["night_stand"]
    assert np.prod(n, 1).mean() < 0.4 * np.prod(r, 1).mean()   # night stands are small
    assert (n[:, 1] / n[:, 0]).mean() > (r[:, 1] / r[:, 0]).mean() + 0.15   # and roughly cubic


# ---------------------------------------------------------------------------- errors

def test_bad_arguments():
    with pytest.raises(ValueError, match="chair"):
        generate("stool", "train", 0)
    with pytest.raises(ValueError, match="train"):
        generate("chair", "val", 0)
    with pytest.raises(ValueError):
        generate("chair", "train", -1)
    with pytest.raises(ValueError):
        generate("chair", "train", 0, seed=-2)
    with pytest.raises(ValueError, match="pedestal"):
        generate("chair", "train", 0, variant="stool")
