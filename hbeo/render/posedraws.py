"""The poses of streamed training views, drawn on the host and, on a GPU, ahead in worker processes.

:class:`PoseDraws` draws the camera pose of image ``i`` of an epoch of
:class:`hbeo.render.torch_datasets.FreshPoses`: object ``i % n`` in pass ``i // n``, from that object's
generator (:func:`hbeo.render.views.object_rng` of the pass's epoch), turned about the optical axis by the
angle of :func:`roll_rng` of the image's reading position when the view is rolled. It holds only the render
settings, the split and the objects' labels, and imports neither torch nor the grids: cheap to pickle.

:class:`DrawAhead` draws the next march's poses in a few worker processes while the device marches and
trains on the current one. Every image has its own generators (two ``default_rng`` seedings, ~16 us each on
a 2-core EPYC VM), so a march of 2,048 images costs ~0.1 s of one host core: as much as the fused marcher
and the network's step together at the paper's size on an H200 (``benchmarks/README.md``). Split between
workers, the same arrays, bit for bit (``tests/test_posedraws.py``).

Arrays: ``pos`` (B,) int64 object positions in the split's record list, ``R`` (B, 3, 3) float64 object ->
camera rotations, ``t`` (B, 3) float64 metres, in the frames of :mod:`hbeo.conventions`.

Imports the foundation and :mod:`hbeo.render.views` only (no torch).
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from hbeo.render.views import SPLIT_CODES, RenderSettings, object_rng
from hbeo.rotations import z_angle_to_matrix

#: :func:`roll_rng`'s tag, which keeps its streams apart from :func:`hbeo.render.views.object_rng`'s
ROLL_TAG = 0x701


def roll_rng(seed: int, split: str, epoch: int, position: int) -> np.random.Generator:
    """The random stream of the camera roll of the image read at ``position`` (in the epoch's reading
    order, counted over the whole epoch: a data-parallel rank's share starts at its offset) of ``epoch``."""
    return np.random.default_rng([int(seed), SPLIT_CODES[split], ROLL_TAG, int(epoch), int(position)])


def rolled(R: np.ndarray, t: np.ndarray, angles) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``R`` (B, 3, 3), ``t`` (B, 3) with each camera first turned about its optical axis by
    ``angles`` (B,) radians: the rotation and the translation turn together."""
    Rz = z_angle_to_matrix(np.asarray(angles, np.float64))
    return Rz @ R, (Rz @ t[:, :, None])[:, :, 0]


@dataclass(frozen=True)
class PoseDraws:
    """The poses of the images of a :class:`~hbeo.render.torch_datasets.FreshPoses` (its ``settings`` with one
    view per object, its ``split``, ``n_objects`` and ``passes`` per epoch)."""

    settings: RenderSettings
    split: str
    n_objects: int
    passes: int

    def positions(self, indices, epoch: int) -> tuple[np.ndarray, list[np.random.Generator]]:
        """Object positions of images ``indices`` of ``epoch``, and each image's generator, before any draw
        (a noisy view draws its sensor noise from it after the pose)."""
        pos, rngs = [], []
        s = self.settings
        for i in indices:
            j, p = divmod(int(i), self.n_objects)
            pos.append(p)
            rngs.append(object_rng(s.seed, self.split, p, int(epoch) * self.passes + j))
        return np.asarray(pos, np.int64), rngs

    def roll_angles(self, epoch: int, keys) -> np.ndarray:
        """The roll angle (radians) of the images read at positions ``keys`` of ``epoch``."""
        return np.array([roll_rng(self.settings.seed, self.split, epoch, int(k)).uniform(0, 2 * np.pi)
                         for k in keys], np.float64)

    def draw(self, indices, epoch: int, roll_keys=None) -> dict:
        """``pos``, ``R`` and ``t`` of images ``indices`` of ``epoch``, rolled by :meth:`roll_angles` of
        ``roll_keys`` when given (one key an image)."""
        pos, rngs = self.positions(indices, epoch)
        R, t = self.settings.view_sampler.sample_each(rngs)
        if roll_keys is not None:
            if len(roll_keys) != len(pos):
                raise ValueError(f"PoseDraws.draw: {len(roll_keys)} roll keys for {len(pos)} images")
            R, t = rolled(R, t, self.roll_angles(epoch, roll_keys))
        return {"pos": pos, "R": R, "t": t}


def _draw(draws: PoseDraws, indices, epoch: int, roll_keys) -> dict:
    return draws.draw(indices, epoch, roll_keys)


def auto_draw_workers(device_type: str) -> int:
    """Worker processes that draw poses ahead: none on the CPU (its cores march and train; a process pool
    would only take them), else up to 8 while leaving two of the host's cores free."""
    return 0 if device_type != "cuda" else max(0, min(8, (os.cpu_count() or 1) - 2))


def drawer_for(views, workers: int | None = None) -> "DrawAhead | None":
    """The :class:`DrawAhead` of a :class:`~hbeo.render.torch_datasets.FreshPoses` ``views`` with ``workers``
    processes (None: :func:`auto_draw_workers` of its caster's device); None when none draws ahead: no
    workers, or sensor noise (it draws from each image's generator after the pose)."""
    if workers is None:
        workers = auto_draw_workers(views.caster().device.type)
    return DrawAhead(views.draws, workers) if workers > 0 and not views.base.settings.noise else None


class DrawAhead:
    """The next march's poses drawn in ``workers`` processes (spawned once, on first use) while this process
    renders and trains on the current one: :meth:`submit` a march, :meth:`take` it back (None when
    something else was asked for, e.g. after a new epoch's plan). Each march is split into ``workers``
    contiguous slices; their arrays, joined, are :meth:`PoseDraws.draw`'s of the whole march."""

    def __init__(self, draws: PoseDraws, workers: int):
        if workers < 1:
            raise ValueError(f"DrawAhead needs at least one worker process, got {workers}")
        self.draws, self.workers = draws, int(workers)
        self._pool = None
        self._pending = None            #: (key, futures)

    def submit(self, key, indices, epoch: int, roll_keys=None) -> None:
        """Start drawing images ``indices`` of ``epoch`` (``roll_keys`` as :meth:`PoseDraws.draw`), known by
        ``key`` (any value compared with ==); a draw not yet taken is dropped."""
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))
        self.cancel()
        idx = np.asarray(indices, np.int64)
        cuts = np.array_split(np.arange(len(idx)), min(self.workers, max(1, len(idx))))
        self._pending = (key, [self._pool.submit(_draw, self.draws, idx[c], int(epoch),
                                                 None if roll_keys is None else np.asarray(roll_keys)[c])
                               for c in cuts if len(c)])

    def take(self, key) -> dict | None:
        """The draw submitted as ``key``, joined (waits for it); None if the pending draw is another's."""
        if self._pending is None or self._pending[0] != key:
            return None
        parts = [f.result() for f in self._pending[1]]
        self._pending = None
        return {k: np.concatenate([p[k] for p in parts]) for k in ("pos", "R", "t")}

    def cancel(self) -> None:
        if self._pending is not None:
            for f in self._pending[1]:
                f.cancel()
            self._pending = None

    def close(self) -> None:
        self.cancel()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __getstate__(self):            # a copy in another process starts without the pool
        return {**self.__dict__, "_pool": None, "_pending": None}
