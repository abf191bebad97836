"""benchmarks/bench_gpu_first_minute.py runs end to end on this CPU (``--cpu-check``: the ci profile's sizes, the
fused kernel under Triton's interpreter) and writes every stage's figures with the keys a GPU run writes."""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hbeo.render import fused

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.skipif(not fused.available(), reason="triton not installed")
def test_the_first_minute_benchmark_runs_on_a_cpu(tmp_path):
    out = tmp_path / "first_minute.json"
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_gpu_first_minute.py"), "--cpu-check",
                    "--out", str(out)], check=True, timeout=300, capture_output=True, text=True)
    d = json.loads(out.read_text())
    assert d["stages_done"] == ["setup", "compile", "agreement", "both", "render", "tiles", "network", "poses"]
    assert d["poses"]["images"] == 64 and [w["identical"] for w in d["poses"]["workers"]] == [True]
    assert d["errors"] == {}, d["errors"]
    s = d["setup"]
    assert s["cpu_check"] and s["interpreter"] and s["image_size"] == [80, 60] and s["grids"] == 10
    a = d["agreement"]
    assert a["images"] == 4 and a["hits_torch"] > 0                  # the interpreter: bit-equal, as test_fused
    assert a["pixels_differ"] == a["hit_torch_only"] == a["hit_triton_only"] == a["images_with_flip"] == 0
    for backend in ("triton", "torch"):
        assert [r["batch"] for r in d["render"][backend]] == [4] and d["render"][backend][0]["images_per_s"] > 0
    assert d["tiles"]["rows"][0]["images_per_s"] > 0
    rows = d["network"]["rows"]
    assert {r["precision"] for r in rows} == {"float32", "amp-float16", "amp-bfloat16"}
    assert all(r.get("images_per_s", 0) > 0 for r in rows), rows
    assert d["both"]["rows"][0]["images_per_s"] > 0
    from hbeo.model.loop import TrainConfig                       # "both" times the training loop's precision
    assert d["both"]["rows"][0]["precision"] == "amp-" + TrainConfig().amp_dtype


def test_a_failing_stage_is_recorded_and_the_json_is_written_after_each(tmp_path):
    path = ROOT / "benchmarks" / "bench_gpu_first_minute.py"
    spec = importlib.util.spec_from_file_location("bench_first_minute", path)
    b = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(b)
    rep = b.Report(tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["stages_done"] == []
    rep.stage("setup", lambda d: d.update(device="x"))

    def fails(d):
        d["partial"] = 1
        raise RuntimeError("no kernel")
    rep.stage("compile", fails)
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["stages_done"] == ["setup", "compile"] and d["setup"]["device"] == "x"
    assert d["compile"]["partial"] == 1 and d["errors"] == {"compile": "RuntimeError: no kernel"}
    assert set(b.STAGES) <= set(d)
