"""Resources checked before they are spent: what a size a user gives will cost, and refusing it up front.

Every size a user can give either runs in bounded memory or is checked here before any work starts:
``rolls`` of a prediction run in fixed-size batches (:data:`ROLL_BATCH` images per network pass) and are
capped at :data:`MAX_ROLLS`; a rendered set is written a few objects at a time, so what grows is one shard
in each worker's memory (:func:`check_render`: every object's views are one task) and the set on disk
(checked against the free space of the output folder); a training set held in memory
(:func:`check_in_memory`) and an evaluation, whose per-view answers are kept until the metrics are computed
(:func:`check_evaluation`), are checked against the memory available now; local worker processes
(:func:`check_workers`) against the memory one of them needs; a network's sizes (``--fc``) against the
memory its training needs (:data:`TRAIN_BYTES_PER_PARAM`, :func:`hbeo.model.network.check_network`). A
refusal is a :class:`ResourceError` (a :class:`~hbeo.errors.HBEOError` and a ValueError: ``python -m hbeo``
prints it as one line, exit 2) that names the option, the estimate and the largest value that would fit.

The byte figures are estimates of the peak, measured by ``benchmarks/bench_memory.py``
(``benchmarks/README.md``); the commands' bounds are stated in ``docs/your-depth-image.md`` ("Bad input").
Imports only the foundation (:mod:`hbeo.errors`), and threadpoolctl when :func:`one_blas_thread` is first called.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from hbeo.errors import HBEOError

#: most camera rolls a prediction averages over: one per degree. The rolls are spaced 360/N degrees
#: apart, and the rotation bins of a bins model (the finest pose output there is) are several degrees
#: wide, so rolls finer than a degree average near-copies of the same input and cannot change the answer,
#: while each one costs a full network pass.
MAX_ROLLS = 360
#: images per network pass when rolls are averaged (rolls x images are sent through in batches of this)
ROLL_BATCH = 32
#: peak bytes per pixel of one image while a shard is rendered and written: the float32 render, the
#: float16 depth, the bool mask, their concatenation and the compressor's buffers (measured, about 10;
#: rounded up)
RENDER_BYTES_PER_PIXEL = 16
#: stored bytes per pixel of a shard image before compression: float16 depth + 1 bit of mask
SHARD_BYTES_PER_PIXEL = 2.125
#: bytes per pixel of a training image held in memory (float16 depth)
MEMORY_BYTES_PER_PIXEL = 2
#: bytes per image of the index arrays ``--data shards`` and ``stream`` keep (epoch order, image -> object)
INDEX_BYTES_PER_IMAGE = 24
#: bytes an evaluation keeps per scored view and method: its completed 30^3 grid (float32), rotations,
#: the row's dictionary (the true grid is the object's, shared)
EVAL_BYTES_PER_VIEW = 30 ** 3 * 4 + 2_000
#: memory one local worker process needs before it renders anything (Python, numpy, torch, a renderer)
WORKER_BYTES = 400 * 2 ** 20
#: most local worker processes per core (rendering is CPU-bound: more only share the cores)
MAX_WORKERS_PER_CORE = 4
#: fraction of the available memory a command may plan to use (the rest: the process itself, the system)
MEMORY_FRACTION = 0.5
#: bytes per parameter of a network being trained: float32 weights, their gradients and Adam's two moments
#: (checked before the network is built: :func:`hbeo.model.network.check_network`)
TRAIN_BYTES_PER_PARAM = 16


class ResourceError(HBEOError, ValueError):
    """A size that would exhaust memory or disk (or the most a command allows); the message names the
    option, the estimate and the largest value that fits."""


def human_bytes(n: float) -> str:
    """``1.5e12`` -> ``'1.5 TB'`` (decimal units)."""
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"


def _count(n: int) -> str:
    """``123456`` -> ``'123,456'``; ``3e9`` -> ``'3.0e9'``."""
    return f"{n:,}" if n < 10_000_000 else f"{n:.1e}".replace("e+0", "e").replace("e+", "e")


def available_memory() -> int:
    """Bytes of memory available to new allocations now: psutil's ``available`` (a dependency), else
    ``MemAvailable`` of /proc/meminfo, else the RLIMIT_AS soft limit, else 8 GiB (a guess), whichever of
    these and the address-space limit (``ulimit -v``) is smaller."""
    avail = None
    try:
        import psutil
        avail = int(psutil.virtual_memory().available)
    except Exception:      # not installed, or no /proc
        try:
            for line in Path("/proc/meminfo").read_text().splitlines():
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
        except (OSError, ValueError, IndexError):
            pass
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft not in (resource.RLIM_INFINITY, -1) and soft > 0:
            avail = soft if avail is None else min(avail, soft)
    except (ImportError, ValueError, OSError):
        pass
    return avail if avail is not None else 8 * 2 ** 30


def free_disk(path) -> int:
    """Free bytes on the file system of ``path`` (its nearest existing parent)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def _positive(option: str, value) -> int:
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise ResourceError(f"{option} {value!r}: must be a positive integer")
    return int(value)


def check_rolls(rolls, option: str = "--rolls") -> int:
    """``rolls`` as an int, or ResourceError above :data:`MAX_ROLLS` (or below 1)."""
    rolls = _positive(option, rolls)
    if rolls > MAX_ROLLS:
        raise ResourceError(f"{option} {_count(rolls)}: that many network passes for one image; at most "
                            f"{MAX_ROLLS} (one roll per degree: finer rolls cannot change the answer)")
    return rolls


def check_render(n_objects: int, views: int, image_size, out_dir, objects_per_shard: int = 1, workers: int | bool = 1,
                 option: str = "--views", free: int | None = None, memory: int | None = None) -> None:
    """Refuse (ResourceError) a rendered set of ``n_objects`` x ``views`` images of ``image_size`` (W, H)
    whose shards would not fit in memory (``min(workers, shards)`` shards of ``objects_per_shard``
    objects rendered at once, :data:`RENDER_BYTES_PER_PIXEL`; ``workers`` local processes, checked with
    :func:`check_workers`, or False: a remote cluster's, counted as one) or whose files would not fit in
    the free space of ``out_dir`` (uncompressed size / 4, a lower bound of what compressed shards take).
    ``free`` and ``memory`` override the measured free disk and available memory (tests)."""
    views = _positive(option, views)
    w, h = image_size
    pixels = int(w) * int(h)
    images = int(n_objects) * views
    n_shards = -(-int(n_objects) // max(1, int(objects_per_shard)))
    at_once = 1 if workers is False else check_workers(min(int(workers), n_shards), memory=memory)
    mem = memory if memory is not None else available_memory()
    budget = mem * MEMORY_FRACTION
    per_view = RENDER_BYTES_PER_PIXEL * pixels * objects_per_shard * at_once
    need = per_view * views
    if need > budget:
        fit = int(budget // per_view)
        raise ResourceError(
            f"{option} {_count(views)}: {_count(images)} images of {n_objects} objects at {w}x{h}; rendering "
            f"{at_once} shard(s) of {objects_per_shard} object(s) at once needs about {human_bytes(need)} of memory, "
            f"{human_bytes(mem)} available; the largest value that fits is {fit:,}"
            + ("" if objects_per_shard == 1 else " (or fewer --objects-per-shard)"))
    disk = images * pixels * SHARD_BYTES_PER_PIXEL / 4
    space = free if free is not None else free_disk(out_dir)
    if disk > space:
        fit = int(space // (int(n_objects) * pixels * SHARD_BYTES_PER_PIXEL / 4))
        raise ResourceError(
            f"{option} {_count(views)}: {_count(images)} images of {n_objects} objects, at least "
            f"{human_bytes(disk)} on disk at {w}x{h} (compressed; {human_bytes(4 * disk)} raw), "
            f"{human_bytes(space)} free in {out_dir}; the largest value that fits is {fit:,}")


def check_in_memory(n_images: int, image_size, coeffs: int = 0, option: str = "--views", per: int = 1,
                    source: str = "memory", value=None, memory: int | None = None) -> None:
    """Refuse (ResourceError) a training set of ``n_images`` images of ``image_size`` (W, H) when what it
    keeps in memory exceeds half the available memory: for ``source="memory"`` every image (float16
    depth, float32 coefficients three times, a rotation); for ``shards`` and ``stream`` the per-image index
    arrays (:data:`INDEX_BYTES_PER_IMAGE`). ``per``: images per unit of ``option`` (the number of
    objects, for --views); ``value``: the option's value, named in the message."""
    w, h = image_size
    if source == "memory":
        per_image = MEMORY_BYTES_PER_PIXEL * int(w) * int(h) + 12 * int(coeffs) + 64
    else:
        per_image = INDEX_BYTES_PER_IMAGE
    need = int(n_images) * per_image
    mem = memory if memory is not None else available_memory()
    if need > mem * MEMORY_FRACTION:
        fit = int(mem * MEMORY_FRACTION // (per_image * max(1, per)))
        what = f"{w}x{h} training images held in memory" if source == "memory" else \
            f"training images (--data {source} keeps {per_image} bytes of index per image)"
        hint = ", or use --data shards or --data stream (bounded memory)" if source == "memory" else ""
        raise ResourceError(
            f"{option}{'' if value is None else ' ' + _count(int(value))}: {_count(int(n_images))} {what} need about {human_bytes(need)}, {human_bytes(mem)} "
            f"available; the largest value that fits is {fit:,}{hint}")


def check_evaluation(n_objects: int, views: int, methods: int = 1, image_size=(0, 0), option: str = "--views",
                     memory: int | None = None) -> None:
    """Refuse (ResourceError) an evaluation of ``n_objects`` x ``views`` query views of ``image_size``
    (W, H) scored by ``methods`` methods whose kept answers (:data:`EVAL_BYTES_PER_VIEW` each) and rendered
    views (:data:`RENDER_BYTES_PER_PIXEL`; a few objects' at a time, counted for all: an upper bound)
    exceed half the available memory."""
    views = _positive(option, views)
    pixels = int(image_size[0]) * int(image_size[1])
    per_view = (EVAL_BYTES_PER_VIEW * max(1, int(methods)) + RENDER_BYTES_PER_PIXEL * pixels) * int(n_objects)
    need = per_view * views
    mem = memory if memory is not None else available_memory()
    if need > mem * MEMORY_FRACTION:
        fit = int(mem * MEMORY_FRACTION // per_view)
        raise ResourceError(
            f"{option} {_count(views)}: {_count(int(n_objects) * views)} query views of {n_objects} objects; "
            f"their answers need about {human_bytes(need)} of memory, {human_bytes(mem)} available; the largest "
            f"value that fits is {fit:,} (or fewer objects: --per-class)")


def usable_cores(fallback: int = 1) -> int:
    """The CPUs this process may run on (its affinity where the OS tells it, else the machine's count, else
    ``fallback``)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or fallback


_BLAS_CONTROLLER = None


def one_blas_thread():
    """A context in which numpy's and scipy's BLAS run on one thread (torch's own threads untouched).

    Inference runs a network (torch's OpenMP threads) and small BLAS products (numpy/scipy OpenBLAS) in
    turn. A BLAS call on several threads leaves its worker threads spinning for a while after it returns;
    on a machine with few cores they then compete with the next network pass, which in ~4 % of queries took
    40-110 ms instead of ~4 ms on the 2-core CPU (``benchmarks/README.md``, "Inference: the BLAS threads").
    Products of one image are too small to gain from threads. The libraries are looked up once a process
    (``threadpoolctl``, ~9 ms); entering and leaving costs ~25 us."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        from threadpoolctl import ThreadpoolController
        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")


def check_workers(workers, option: str = "--workers", memory: int | None = None) -> int:
    """``workers`` as an int, or ResourceError when that many local processes (:data:`WORKER_BYTES` each)
    exceed the available memory, or there are more than :data:`MAX_WORKERS_PER_CORE` per core."""
    workers = _positive(option, workers)
    cores = os.cpu_count() or 1
    if workers > MAX_WORKERS_PER_CORE * cores:
        raise ResourceError(f"{option} {_count(workers)}: more than {MAX_WORKERS_PER_CORE} processes per core "
                            f"({cores} cores here) only slow each other down; the largest sensible value is "
                            f"{MAX_WORKERS_PER_CORE * cores}")
    mem = memory if memory is not None else available_memory()
    if workers * WORKER_BYTES > mem:
        raise ResourceError(
            f"{option} {_count(workers)}: {_count(workers)} processes need about "
            f"{human_bytes(workers * WORKER_BYTES)} ({human_bytes(WORKER_BYTES)} each), {human_bytes(mem)} "
            f"available; the largest value that fits is {max(1, int(mem // WORKER_BYTES)):,} "
            f"(this machine has {os.cpu_count()} cores)")
    return workers
