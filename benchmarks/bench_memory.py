"""Peak memory of each batch command (issue #30 item 2): bounded as the sizes grow, refusals cheap.

Each case runs ``python -m hbeo ...`` in a fresh child under ``/usr/bin/time -f %M`` and reports its exit
status, wall time and peak resident memory (the largest process of the command's tree that the child waited
for: a Dask worker's or the render child's own peak where it is larger). Inputs: the reference model
``results/cpu-modelnet10-vox30/model.hbeo`` (rotation bins, 80x60) and a synthetic depth image for
``predict``; the procedural dataset at the ``ci`` profile (30 test objects) for ``render`` and
``evaluate``, in a temporary folder; where ``HBEO_VOX30`` names the ModelNet10 grid archive, also ``render`` of
its ``ci`` training objects on 2 Dask workers, one object a shard (one task each: a task once carried the whole
split's grids). The refused cases (``--rolls 100000``, ``--views 100000000``)
must exit 2 in about the time it takes to start.

Usage: python benchmarks/bench_memory.py [--quick] [--work DIR] [--only TEXT]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from hbeo.config import vox30_path  # noqa: E402
MODEL = ROOT / "results" / "cpu-modelnet10-vox30" / "model.hbeo"


def measure(args: list[str], env: dict) -> tuple[int, float, float, str]:
    """(exit status, seconds, peak RSS in MB, last stderr line) of ``python -m hbeo ARGS``."""
    t0 = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-f", "MAXRSS %M", sys.executable, "-m", "hbeo", *args],
                         capture_output=True, text=True, env=env)
    lines = out.stderr.strip().splitlines()
    rss = next(float(x.split()[1]) / 1024 for x in reversed(lines) if x.startswith("MAXRSS"))
    last = next((x for x in lines if x.startswith("error:")), "")
    return out.returncode, time.perf_counter() - t0, rss, last


def depth_png(path: Path) -> None:
    """A box 1.5 m away seen by the reference model's 80x60 camera (16-bit PNG, millimetres)."""
    from PIL import Image
    d = np.zeros((60, 80), np.uint16)
    d[20:42, 25:55] = 1500
    d[20:26, 25:55] = 1450
    Image.fromarray(d).save(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer, smaller cases")
    ap.add_argument("--work", help="scratch folder (default: a temporary one)")
    ap.add_argument("--only", help="run only the cases whose name contains this text")
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench_memory_"))
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT), HBEO_CACHE=str(work / "cache"))
    depth_png(work / "d.png")
    run = str(work / "run")
    predict = ["predict", "--model", str(MODEL), "--depth", str(work / "d.png"), "--intrinsics", "65.6,65.6,39.5,29.5",
               "--out", str(work / "p.json")]
    render = ["render", "--profile", "ci", "--split", "test", "--quiet", "--workers", "1"]
    cases = [("predict --rolls 1", predict + ["--rolls", "1"]),
             ("predict --rolls 36", predict + ["--rolls", "36"]),
             ("predict --rolls 360", predict + ["--rolls", "360"]),
             ("predict --rolls 100000 (refused)", predict + ["--rolls", "100000"])]
    for v in ((8, 64) if a.quick else (8, 64, 256)):
        cases.append((f"render ci test --views {v} ({30 * v:,} images)", render + ["--views", str(v), "--out", f"{run}{v}"]))
    cases.append(("render ci test --views 100000000 (refused)", render + ["--views", "100000000", "--out", run]))
    vox30 = vox30_path()                     # the project's resolution of HBEO_VOX30 (a file or its folder)
    if vox30 is not None and vox30.is_file():
        env["HBEO_VOX30"] = str(vox30)
        cases.append(("render modelnet10-vox30 ci train --views 2 --workers 2 --objects-per-shard 1 (60 Dask tasks)",
                      ["render", "--dataset", "modelnet10-vox30", "--profile", "ci", "--quiet", "--workers", "2",
                       "--objects-per-shard", "1", "--views", "2", "--out", f"{run}vox30"]))
    for v in ((1, 8) if a.quick else (1, 8, 32)):
        cases.append((f"evaluate procedural --per-class 1 --views {v}",
                      ["evaluate", "--model", str(MODEL), "--dataset", "procedural", "--per-class", "1", "--views",
                       str(v), "--out", str(work / f"e{v}.json"), "--quiet"]))
    cases.append(("evaluate --views 100000000 (refused)",
                  ["evaluate", "--model", str(MODEL), "--dataset", "procedural", "--views", "100000000",
                   "--out", str(work / "e.json"), "--quiet"]))
    print("| command | exit | seconds | peak RSS (MB) |\n| --- | ---: | ---: | ---: |")
    for name, args in cases:
        if a.only and a.only not in name:
            continue
        code, s, rss, err = measure(args, env)
        print(f"| `{name}` | {code} | {s:.1f} | {rss:.0f} |" + (f" {err[:160]}" if err else ""), flush=True)


if __name__ == "__main__":
    main()
