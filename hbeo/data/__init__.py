"""Objects and their 30^3 grids: the paper's data (Sec. IV, "ModelNet10").

Owns the sources of objects (:mod:`~hbeo.data.datasets`: procedural, ModelNet10 meshes, the
ModelNet10 30^3 grid file, a user's folder), the procedural generator (:mod:`~hbeo.data.procedural`,
its part library :mod:`~hbeo.data.procedural_parts` and its furniture families:
:mod:`~hbeo.data.procedural_bathroom`, :mod:`~hbeo.data.procedural_beds`, :mod:`~hbeo.data.procedural_seating`,
:mod:`~hbeo.data.procedural_storage`, :mod:`~hbeo.data.procedural_tables`, :mod:`~hbeo.data.procedural_screens`),
reading meshes (:mod:`~hbeo.data.meshio`), voxelization into the 3D ShapeNets grid layout
(:mod:`~hbeo.data.voxel`), cached grid sets (:mod:`~hbeo.data.gridset`), one grid file of a whole dataset in the
published layout (:mod:`~hbeo.data.gridfile`), near-duplicate objects and the validation split that
keeps them together (:mod:`~hbeo.data.dedup`) and the ModelNet10 download (:mod:`~hbeo.data.download`).

May import: the foundation modules (:mod:`hbeo.conventions`, :mod:`hbeo.config`,
:mod:`hbeo.errors`, :mod:`hbeo.storage`, :mod:`hbeo.rotations`, :mod:`hbeo.rundir`) only.
"""
