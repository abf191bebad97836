"""This machine, described: the CPU, cores, memory, GPU, torch's threads and CPU kernels, and the platform.

A run's ``manifest.json`` records where its models were trained (:mod:`hbeo.report.provenance`), and each
evaluation file where its times were measured (``hardware`` in :mod:`hbeo.evaluation.evaluate`'s metrics):
Table II's note names the machines its times come from (:func:`hbeo.report.tables.table2_note`).
:func:`describe` is the one-line form both print.

May import: nothing of hbeo (torch, lazily, only to describe the hardware).
"""
from __future__ import annotations

import os
import platform
from pathlib import Path


def hardware() -> dict:
    """CPU model, cores, memory (GiB) and GPU of this machine, torch's thread count and the CPU kernels torch
    dispatches to (``cpu_capability``, e.g. ``AVX2`` or ``AVX512``: two machines that differ there train the same
    seed to slightly different weights, while inference reproduces; docs/reproduce.md, "Determinism")."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = None
    try:
        mem = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30, 1)
    except (ValueError, OSError, AttributeError):
        pass
    gpu = None
    try:
        import torch
        if torch.cuda.is_available():
            gpu = torch.cuda.get_device_name(0)
        threads = torch.get_num_threads()
    except Exception:   # noqa: BLE001 (torch missing or broken: the rest is still described)
        threads = None
    try:
        capability = torch.backends.cpu.get_cpu_capability()
    except Exception:   # noqa: BLE001 (an older torch without it, or none)
        capability = None
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": mem, "gpu": gpu, "torch_threads": threads,
            "cpu_capability": capability, "platform": platform.platform()}


def describe(hw: dict) -> str:
    """One line for a :func:`hardware` record: ``CPU, N cores, GPU: name or none, torch threads: T``."""
    threads = hw.get("torch_threads")
    return (f"{hw.get('cpu') or 'unknown CPU'}, {hw.get('cores') or '?'} cores, GPU: {hw.get('gpu') or 'none'}, "
            f"torch threads: {threads if threads is not None else 'unknown'}")
