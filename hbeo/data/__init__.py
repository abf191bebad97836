"""Objects and their 30^3 grids: the paper's data (Sec. IV, "ModelNet10").

Owns the sources of objects (:mod:`~hbeo.data.datasets`: procedural, ModelNet10 meshes, the
ModelNet10 30^3 grid file, a user's folder), the procedural generator, reading meshes
(:mod:`~hbeo.data.meshio`), voxelization into the 3D ShapeNets grid layout
(:mod:`~hbeo.data.voxel`), cached grid sets (:mod:`~hbeo.data.gridset`) and the ModelNet10
download (:mod:`~hbeo.data.download`).

May import: the foundation modules (:mod:`hbeo.conventions`, :mod:`hbeo.config`,
:mod:`hbeo.errors`, :mod:`hbeo.storage`, :mod:`hbeo.rotations`, :mod:`hbeo.rundir`) only.
"""
