"""Procedural ModelNet10-like furniture: the embedded default dataset.

``generate(cls, split, index, seed=0)`` builds one mesh of a ModelNet10 class from
parameterized parts; it is used instead of the real ModelNet10 meshes when nothing
has been downloaded. Every class has several structural variants (:data:`VARIANTS`),
each with continuous random sizes and proportions, so that a class is a
distribution of shapes, not a template.

Units
    Metres, realistic sizes (chair seats ~0.45 m high, beds ~2 m long, ...).

Frame (ModelNet's per-class alignment, see :mod:`hbeo.conventions`)
    Right-handed, +z up. Every mesh rests on z = 0 (its minimum z is exactly 0) and
    its bounding box is centred on x = y = 0.

    * chair, bed, toilet: the back (chair back, headboard, cistern) is toward +y;
      the object faces -y.
    * sofa: the back is toward +x; the sofa faces -x (its length runs along y).
    * desk, dresser, night_stand, monitor, bathtub, table: the front (drawer
      fronts, the screen, the side a person stands at) faces -y.
    * bed and bathtub: the long axis runs along y. Rectangular tables and desks
      have their long side along x.

Meshes
    A mesh is the concatenation of closed (watertight, outward-wound) primitive
    parts from :mod:`hbeo.data.procedural_parts`: boxes, vertical (elliptical) frusta
    and cylinders, hollow tubes, and cylinders between two points, plus the
    sub-assemblies several classes share (pedestals, drawers, carcasses). Parts may
    overlap; no boolean operations are done. Hollow objects (bathtub basin, toilet bowl) are modelled as floor plus
    walls, so their cavity is open at the top and a voxelizer that fills closed
    cavities leaves it empty. A mesh has hundreds to a few thousand faces and is
    built in about a millisecond.

Determinism
    A mesh is a pure function of ``(cls, split, index, seed, variant)``: its random
    stream is ``np.random.default_rng([seed, class_index(cls), split_code, index])``
    with split_code 0 for "train" and 1 for "test"; any object can be made alone.

Layout
    This module is the catalogue: :data:`VARIANTS`, the variant weights and :func:`generate`.
    The class builders live with their furniture family, each following the frame
    conventions above: :mod:`hbeo.data.procedural_bathroom` (bathtub, toilet),
    :mod:`hbeo.data.procedural_beds` (bed), :mod:`hbeo.data.procedural_seating` (chair,
    sofa), :mod:`hbeo.data.procedural_storage` (dresser, night stand),
    :mod:`hbeo.data.procedural_tables` (desk, table) and :mod:`hbeo.data.procedural_screens`
    (monitor). The part library they share is :mod:`hbeo.data.procedural_parts`.

Imports :mod:`hbeo.conventions`, the family modules, :mod:`hbeo.data.procedural_parts`,
numpy and trimesh.
"""
from __future__ import annotations

import numpy as np
import trimesh

from hbeo.conventions import CLASSES, SPLITS, class_index
from hbeo.data import procedural_bathroom as _bathroom
from hbeo.data import procedural_beds as _beds
from hbeo.data import procedural_screens as _screens
from hbeo.data import procedural_seating as _seating
from hbeo.data import procedural_storage as _storage
from hbeo.data import procedural_tables as _tables
from hbeo.data.procedural_parts import assemble

__all__ = ["VARIANTS", "VERSION", "generate"]

#: Generator version: bump whenever the geometry produced for some arguments changes
#: (it is part of the dataset fingerprint, so caches of the old shapes are not reused).
VERSION = 1

#: Structural variants per class; ``generate(..., variant=name)`` forces one.
VARIANTS: dict[str, tuple[str, ...]] = {
    "bathtub": ("rect", "rect/feet", "oval", "alcove"),
    "bed": ("legs", "legs/headboard", "legs/headboard/footboard",
            "base", "base/headboard", "base/headboard/footboard"),
    "chair": tuple(f"{a}/{b}/{c}" for a in ("noarms", "arms")
                   for b in ("legs", "pedestal") for c in ("straight", "slanted")),
    "desk": ("legs", "panels", "drawers_one_side", "drawers_both_sides"),
    "dresser": ("wide/legs", "wide/plinth", "tall/legs", "tall/plinth"),
    "monitor": ("stand/plate", "stand/disc", "wall", "crt"),
    "night_stand": ("drawers", "shelf", "drawer_shelf"),
    "sofa": ("arms2", "arms1", "arms0", "l_shape"),
    "table": ("rect/legs", "rect/pedestal", "round/legs", "round/pedestal"),
    "toilet": ("seat", "seat/lid_up", "seat/lid_down", "no_seat"),
}


def _chair_weights() -> tuple[float, ...]:
    p = {"arms": 0.35, "noarms": 0.65, "pedestal": 0.3, "legs": 0.7, "slanted": 0.4, "straight": 0.6}
    return tuple(float(np.prod([p[w] for w in v.split("/")])) for v in VARIANTS["chair"])


#: Relative frequency of each variant (uniform where a class is not listed).
_WEIGHTS: dict[str, tuple[float, ...]] = {
    "bed": (0.1, 0.25, 0.2, 0.1, 0.2, 0.15),
    "chair": _chair_weights(),
    "desk": (0.25, 0.2, 0.3, 0.25),
    "monitor": (0.4, 0.25, 0.15, 0.2),
    "night_stand": (0.55, 0.2, 0.25),
    "sofa": (0.5, 0.15, 0.1, 0.25),
    "toilet": (0.35, 0.3, 0.25, 0.1),
}


#: The builder of each class: the object's random stream and a variant name -> its parts (before centring).
_BUILDERS = {
    "bathtub": _bathroom.bathtub, "bed": _beds.bed, "chair": _seating.chair, "desk": _tables.desk,
    "dresser": _storage.dresser, "monitor": _screens.monitor, "night_stand": _storage.night_stand,
    "sofa": _seating.sofa, "table": _tables.table, "toilet": _bathroom.toilet,
}
assert set(_BUILDERS) == set(CLASSES) == set(VARIANTS)


# ----------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------

def generate(cls: str, split: str, index: int, seed: int = 0, variant: str | None = None) -> trimesh.Trimesh:
    """One procedural mesh of class ``cls`` (metres, +z up, min z = 0, bbox centred in x, y).

    cls: a ModelNet10 class name; split: "train" or "test"; index >= 0 and seed >= 0
    select the object; variant: one of ``VARIANTS[cls]`` to force a structure
    (the random sizes are unchanged), None to draw it. ``mesh.metadata`` holds
    "class", "variant" (e.g. "chair/arms/pedestal/slanted"), "split", "index", "seed".
    """
    if cls not in CLASSES:
        raise ValueError(f"unknown class {cls!r}; expected one of {', '.join(CLASSES)}")
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"index must be a non-negative integer, got {index!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    names = VARIANTS[cls]
    if variant is not None and variant not in names:
        raise ValueError(f"unknown variant {variant!r} for {cls}; expected one of {', '.join(names)}")
    rng = np.random.default_rng([int(seed), class_index(cls), SPLITS.index(split), int(index)])
    weights = np.asarray(_WEIGHTS.get(cls, (1.0,) * len(names)), dtype=np.float64)
    drawn = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    variant = drawn if variant is None else variant
    mesh = assemble(_BUILDERS[cls](rng, variant))
    mesh.metadata.update({"class": cls, "variant": f"{cls}/{variant}", "split": split,
                          "index": int(index), "seed": int(seed)})
    return mesh
