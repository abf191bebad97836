"""hbeo: Hybrid Bayesian Eigenobjects (Burchfiel & Konidaris), reproduced and extended.

One segmented depth image of an unseen object -> class, 3-DOF pose and full 3D shape.
Conventions (frames, grid layout) live in :mod:`hbeo.conventions`; run sizes and data
paths in :mod:`hbeo.config`.
"""
__version__ = "0.1.0"

from hbeo.conventions import CLASSES  # noqa: F401
