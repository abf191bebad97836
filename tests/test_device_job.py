"""The device job (maintainer/device_job.py, device_prepare.sh, device_job.sh) on this CPU with the ``ci`` profile:
the same scripts a lent GPU machine runs. A call that runs out of waiting leaves the worker running and exits 3;
a later call waits on; a worker killed mid-training is restarted from its checkpoint; the packed files fit the
device tool's transfer limits (at most 8 files, 16 MiB each) and the model parts join to the run's model."""
import gzip
import hashlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "maintainer" / "device_job.py"


#: Python packages hbeo can use that the lent GPU machine's image lacks (/work/.library/device/KINDS.md, read
#: 2026-11-17; trimesh and pooch travel as wheels, maintainer/device_prepare.sh): the device job must not need them.
ABSENT_ON_DEVICE = ("pyrender", "embreex", "dask", "distributed", "plotly", "papermill", "nbformat", "nbconvert",
                    "latex2mathml", "IPython", "OpenGL", "jupyterlab", "nbval")
SITECUSTOMIZE = f'''import importlib.abc, sys
class _Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {set(ABSENT_ON_DEVICE)!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not on the device)", name=name)
sys.meta_path.insert(0, _Absent())
'''


def _device_like(tmp_path) -> str:
    """A PYTHONPATH entry whose sitecustomize makes :data:`ABSENT_ON_DEVICE` unimportable, as on the device."""
    d = tmp_path / "device_like"
    d.mkdir(exist_ok=True)
    (d / "sitecustomize.py").write_text(SITECUSTOMIZE)
    return str(d)


def _job(run, out, *extra, wait=600, pythonpath=(), env=None):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([*pythonpath, str(ROOT)]), **(env or {})}
    return subprocess.run([sys.executable, str(JOB), "--profile", "ci", "--dataset", "procedural", "--run", str(run),
                           "--out", str(out), "--wait", str(wait), "--checkpoint-every", "5", *extra],
                          capture_output=True, text=True, env=env, timeout=900)


def _script_module(name: str):
    """A maintainer script as a module (``device_job``, ``device_land``)."""
    spec = importlib.util.spec_from_file_location(f"{name}_script", ROOT / "maintainer" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _device_job_module():
    return _script_module("device_job")


def _kill_worker(run) -> None:
    """Kill the worker a call left running in ``run`` (its process group), if any."""
    state = run / "job_state.json"
    pid = json.loads(state.read_text()).get("pid") if state.exists() else None
    if pid:
        try:
            os.killpg(os.getpgid(pid), signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.slow
def test_device_job_trains_in_the_background_resumes_a_killed_worker_and_packs_under_the_limits(tmp_path):
    run, out = tmp_path / "run", tmp_path / "out"
    first = _job(run, out, wait=0)                       # starts the worker, returns at once
    assert first.returncode == 3, first.stdout + first.stderr
    assert "still running" in first.stdout
    state = json.loads((run / "job_state.json").read_text())
    ckpt = run / "train_model" / "checkpoint.pt"
    deadline = time.time() + 600
    while not ckpt.exists() and time.time() < deadline:  # the first checkpoint, then cut the worker
        time.sleep(0.5)
    assert ckpt.exists(), (run / "job.log").read_text()[-3000:]
    state = json.loads((run / "job_state.json").read_text())
    os.killpg(os.getpgid(state["pid"]), signal.SIGKILL)
    time.sleep(1)
    second = _job(run, out)                              # restarts it from the checkpoint and waits to the end
    assert second.returncode == 0, second.stdout + second.stderr + (run / "job.log").read_text()[-3000:]
    assert "restarting it from its checkpoint" in second.stdout
    lease = json.loads((out / "lease.json").read_text())
    assert lease["status"] == "done" and lease["profile"] == "ci"
    assert lease["resumed_from_step"] and lease["resumed_from_step"] > 0
    assert lease["images_seen"] == lease["steps"] * lease["batch_size"] > 0
    assert lease["device"].startswith("cpu")
    assert 0 < lease["metrics"]["n_queries"] and 0 <= lease["metrics"]["class_mean_accuracy"] <= 1
    files = sorted(out.iterdir())
    assert len(files) <= 8 and all(f.stat().st_size <= 16 * 2**20 for f in files)
    assert {"lease.json", "eval_hbeo_3dof.json", "train_log.csv", "provenance.json", "job.log"} <= {f.name for f in files}
    ev = json.loads((out / "eval_hbeo_3dof.json").read_text())       # a chunk of views per network call
    assert ev["batched"] is True and ev["request"]["batched"] is True and ev["completion"]["empty"] == 0
    joined = gzip.decompress(b"".join(p.read_bytes() for p in sorted(out.glob("model.hbeo.gz.part*"))))
    assert joined == (run / "model.hbeo").read_bytes()
    assert lease["weights_rounded_to"] == "bfloat16" and lease["unrounded_model_sha256"] != lease["model_sha256"]
    from hbeo.model.inference import HBEO
    import torch
    w = torch.cat([p.detach().flatten() for p in HBEO.load(run / "model.hbeo").net.parameters()])
    assert torch.equal(w, w.to(torch.bfloat16).float())          # the weights that came back are bf16 values
    third = _job(run, tmp_path / "out2")                 # finished: a later call only packs again
    assert third.returncode == 0 and "started" not in third.stdout


def test_device_job_gzips_and_splits_a_model_over_15_mib_into_parts(tmp_path, monkeypatch):
    device_job = _device_job_module()
    run = tmp_path / "run"
    run.mkdir()
    blob = os.urandom(2 * device_job.PART_BYTES + 123)
    (run / "model.hbeo").write_bytes(blob)
    out = tmp_path / "out"
    files = device_job.pack(run, out, {"status": "running"})         # not final yet: no model goes
    assert [f.name for f in files] == ["lease.json"] and "model_sha256" not in json.loads(files[0].read_text())
    packed = {}
    files = device_job.pack(run, out, {"status": "running", "model_final": True}, packed)
    parts = sorted(out.glob("model.hbeo.gz.part*"))
    assert len(parts) == 3 and all(p.stat().st_size == device_job.PART_BYTES for p in parts[:2])
    assert gzip.decompress(b"".join(p.read_bytes() for p in parts)) == blob
    lease = json.loads((out / "lease.json").read_text())
    assert lease["model_bytes"] == len(blob) and len(lease["model_sha256"]) == 64
    assert len(files) == 4 and sorted(p.name for p in out.iterdir()) == sorted(f.name for f in files)  # no temporary
    for p in parts:                                                   # packed again while waiting: not gzipped again
        p.write_bytes(b"left as it was")
    device_job.pack(run, out, {"status": "done", "model_final": True}, packed)
    assert all(p.read_bytes() == b"left as it was" for p in parts)
    assert json.loads((out / "lease.json").read_text())["model_sha256"] == lease["model_sha256"]
    small = os.urandom(device_job.PART_BYTES // 2)                    # a changed model: packed again, fewer parts
    (run / "model.hbeo").write_bytes(small)
    device_job.pack(run, out, {"status": "done", "model_final": True}, packed)
    assert [p.name for p in sorted(out.glob("model.hbeo.gz.part*"))] == ["model.hbeo.gz.part00"]
    assert gzip.decompress((out / "model.hbeo.gz.part00").read_bytes()) == small
    (run / "model.hbeo").write_bytes(os.urandom(3 * device_job.PART_BYTES + 1))   # too big even gzipped: refused
    with pytest.raises(SystemExit, match="at most 3 fit"):
        device_job.pack(run, tmp_path / "out2", {"status": "done", "model_final": True})


@pytest.mark.slow
def test_a_call_stopped_by_its_time_limit_packs_what_exists_and_leaves_the_worker_running(tmp_path):
    """The device tool ends a call that outruns its limit (SIGTERM): the call packs what exists (its earlier packs
    are in --out already) and exits 3; the worker, in its own session, trains on."""
    run, out = tmp_path / "run", tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    call = subprocess.Popen([sys.executable, str(JOB), "--profile", "ci", "--dataset", "procedural", "--run", str(run),
                             "--out", str(out), "--wait", "600", "--checkpoint-every", "5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.time() + 120
        while not (out / "lease.json").exists() and time.time() < deadline:   # the first pack, while it waits
            time.sleep(0.2)
        assert (out / "lease.json").exists()
        call.send_signal(signal.SIGTERM)
        stdout, stderr = call.communicate(timeout=60)
        assert call.returncode == 3, stdout + stderr
        assert "stopped by a signal" in stdout and "packed lease.json" in stdout
        state = json.loads((run / "job_state.json").read_text())
        assert _device_job_module()._alive(state["pid"])        # the worker goes on
        lease = json.loads((out / "lease.json").read_text())
        assert lease["status"] in ("starting", "running") and not list(out.glob("*.tmp"))
    finally:
        call.kill()
        _kill_worker(run)


def test_device_prepare_copies_the_grids_and_ignores_its_folder(tmp_path, vox30_file):
    env = {**os.environ, "WHEELS": "0", "HBEO_VOX30": str(vox30_file), "PY": sys.executable,
           "PYTHONPATH": str(ROOT)}
    dest = tmp_path / "dev"
    r = subprocess.run(["bash", str(ROOT / "maintainer" / "device_prepare.sh"), str(dest)], capture_output=True,
                       text=True, env=env, timeout=120)
    assert r.returncode in (0, 3), r.stderr                      # 3: this tree with dest passes 64 MiB
    assert (dest / "modelnet10_vox30.npz").read_bytes() == Path(vox30_file).read_bytes()
    assert "to travel" in r.stdout and (r.returncode == 0 or "device_tree.sh slim" in r.stderr)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    src = json.loads((dest / "source.json").read_text())          # the commit that travels, for lease.json
    assert src["commit"] == head and isinstance(src["dirty"], bool)
    # over the limit: exit 3 with the largest files listed (sort | head ended with SIGPIPE, 141, in CI)
    r = subprocess.run(["bash", str(ROOT / "maintainer" / "device_prepare.sh"), str(dest)], capture_output=True,
                       text=True, env={**env, "LIMIT_MIB": "0"}, timeout=120)
    assert r.returncode == 3, r.stderr
    listed = r.stderr.split("The largest files that travel:")[1].split()
    assert len(listed) == 10 and all(n.isdigit() for n in listed[::2])


@pytest.mark.slow
def test_device_job_with_a_budget_times_a_calibration_and_trains_the_steps_that_fit(tmp_path):
    run, out = tmp_path / "run", tmp_path / "out"
    # with training flags and the validation split (choosing a recipe: never the test split)
    # (and a batch, learning rate and warm-up share of the budgeted steps, as batch_choice's large batch passes on)
    r = _job(run, out, "--budget", "120", "--calibrate", "3", "--eval-reserve", "20", "--split", "val",
             "--class-balance", "sampler", "--seed", "1", "--loss-weights", "2,1,1", "--fc", "32,16,16",
             "--batch-size", "8", "--lr", "0.002", "--warmup-share", "0.25")
    assert r.returncode == 0, r.stdout + r.stderr + (run / "job.log").read_text()[-3000:]
    lease = json.loads((out / "lease.json").read_text())
    assert lease["split"] == "val" and lease["train_options"] == {"class_balance": "sampler", "seed": 1,
                                                                  "loss_weights": "2,1,1", "fc": "32,16,16",
                                                                  "batch_size": 8, "lr": 0.002}
    assert lease["batch_size"] == 8 and lease["lr"] == 0.002 and lease["images_seen"] == 8 * lease["steps"]
    assert lease["warmup_steps"] == max(1, round(0.25 * lease["budget"]["max_steps"]))
    assert lease["provenance"]["options"]["warmup_steps"] == lease["warmup_steps"]
    assert lease["provenance"]["options"]["batch_size"] == 8 and lease["provenance"]["options"]["lr"] == 0.002
    assert lease["provenance"]["options"]["fc"] == [32, 16, 16]
    assert lease["provenance"]["options"]["loss"] == {"classification": 2.0, "pose": 1.0, "coeffs": 1.0}
    val = json.loads((out / "eval_val_hbeo_3dof.json").read_text())
    assert val["split"] == "val" and not (out / "eval_hbeo_3dof.json").exists()
    assert lease["provenance"]["options"]["class_balance"] == "sampler" and lease["provenance"].get("seed") == 1
    b = lease["budget"]
    assert b["calibration_steps"] == 3 and b["step_s"] > 0 and b["seconds"] == 120
    assert b["host_waits"] == 0 and b["host_wait_sites"] == {}        # a CPU: torch's sync debug mode is CUDA's
    assert 3 <= lease["steps"] <= b["max_steps"]   # the chosen steps, or the profile's all when fewer
    assert (run / "calibration.hbeo").exists() and (run / "model.hbeo").exists() and b["warmup_steps"] == 5
    assert "budget 120 s" in (run / "job.log").read_text()
    bad = _job(tmp_path / "run2", tmp_path / "out3", "--budget", "-5")
    assert bad.returncode == 2 and "--budget" in bad.stderr
    for flags in (["--warmup-share", "0.1"], ["--budget", "9", "--warmup-share", "1.5"],
                  ["--budget", "9", "--warmup-share", "0.1", "--warmup-steps", "7"]):
        bad = _job(tmp_path / "run2", tmp_path / "out3", *flags)
        assert bad.returncode == 2 and "--warmup-share" in bad.stderr, flags


def _tiers(job, **validated):
    """LARGE_BATCHES with the given outcomes (``b512=True``, ``b256=None``, ...)."""
    return tuple({**t, "validated": validated.get(f"b{t['batch_size']}", t["validated"])} for t in job.LARGE_BATCHES)


def test_the_batch_is_a_larger_one_only_when_validated_on_the_fused_marcher_and_fast_enough(monkeypatch):
    job = _device_job_module()
    from argparse import Namespace
    from hbeo.config import get_profile
    full = get_profile("full").recipe
    assert (full.batch_size, full.lr) == (128, 1e-3)            # the rule's comparison point is the full job's
    assert [t["batch_size"] for t in job.LARGE_BATCHES] == [512, 256]            # the largest first
    args = Namespace(budget=700.0, batch_size=None, lr=None, warmup_steps=None, warmup_share=None)
    both = {"both": {"rows": [{"batch": 128, "images_per_s": 15000.0}, {"batch": 256, "images_per_s": 19500.0},
                              {"batch": 512, "images_per_s": 25000.0}]}}
    monkeypatch.setattr(job, "LARGE_BATCHES", _tiers(job, b512=None, b256=True))
    got = job.batch_choice(both, "auto", full, args)
    assert (got["batch_size"], got["lr"], got["speedup"]) == (256, 4e-3, 1.3) and "1.30 times" in got["reason"]
    assert got["warmup_share"] == 1 / 13 and "passed over batch 512: batch512-e18-seeds is pending" in got["reason"]
    monkeypatch.setattr(job, "LARGE_BATCHES", _tiers(job, b512=True, b256=True))
    got = job.batch_choice(both, "auto", full, args)              # 512 at 1.67 times: short of its 1.8
    assert got["batch_size"] == 256 and "batch 512: too little faster" in got["reason"] and "1.67 times" in got["reason"]
    fast = {"both": {"rows": [{"batch": 128, "images_per_s": 15000.0}, {"batch": 256, "images_per_s": 19500.0},
                              {"batch": 512, "images_per_s": 27000.0}]}}
    got = job.batch_choice(fast, "auto", full, args)
    assert (got["batch_size"], got["lr"], got["warmup_share"], got["speedup"]) == (512, 8e-3, 1 / 18, 1.8)
    cut = {"both": {"rows": fast["both"]["rows"][:2]}}           # 512 not measured: the next one down decides
    got = job.batch_choice(cut, "auto", full, args)
    assert got["batch_size"] == 256 and "batch 512: the both stage did not measure" in got["reason"]
    monkeypatch.setattr(job, "LARGE_BATCHES", _tiers(job, b512=False, b256=True))
    got = job.batch_choice(fast, "auto", full, args)
    assert got["batch_size"] == 256 and "batch512-e18-seeds did not pass" in got["reason"]
    slow = {"both": {"rows": [{"batch": 128, "images_per_s": 15000.0}, {"batch": 256, "images_per_s": 19400.0}]}}
    got = job.batch_choice(slow, "auto", full, args)
    assert got["batch_size"] is None and got["speedup"] == 1.293 and "too little faster" in got["reason"]
    for report, gridcast, recipe, a, word in (
            (both, "torch", full, args, "torch march"),
            ({"both": {"rows": both["both"]["rows"][:1]}}, "auto", full, args, "did not measure"),
            ({}, "auto", full, args, "did not measure"),
            (both, "auto", get_profile("cpu").recipe, args, "this profile trains at batch 64"),
            (both, "auto", full, Namespace(**{**vars(args), "budget": None}), "no --budget"),
            (both, "auto", full, Namespace(**{**vars(args), "lr": 2e-3}), "command line")):
        got = job.batch_choice(report, gridcast, recipe, a)
        assert got["batch_size"] is None and word in got["reason"], (word, got)
    for validated, word in ((None, "pending"), (False, "did not pass")):
        monkeypatch.setattr(job, "LARGE_BATCHES", _tiers(job, b512=validated, b256=validated))
        got = job.batch_choice(both, "auto", full, args)
        assert got["batch_size"] is None and word in got["reason"] and "batch256-e13-seeds" in got["reason"], got


def test_the_batch_rule_follows_its_experiments_and_reaches_the_worker(tmp_path, monkeypatch):
    job = _device_job_module()
    import tomllib
    for tier in job.LARGE_BATCHES:                        # each outcome is its experiment's, nothing else
        spec, = (ROOT / "experiments" / "cpu-modelnet10-vox30").glob(f"*-{tier['experiment']}.toml")
        spec = tomllib.loads(spec.read_text())
        assert tier["validated"] == {"pending": None, "chosen": True, "not chosen": False}[spec["status"]], tier
        assert f"--batch-size {tier['batch_size']} --lr {tier['lr']:g}" in spec["row"]["command"]
    seen = {}

    class Popen:
        def __init__(self, cmd, **kw):
            seen["cmd"], self.pid = cmd, 12345
    monkeypatch.setattr(job.subprocess, "Popen", Popen)
    from argparse import Namespace
    args = Namespace(profile="full", dataset="modelnet10-vox30", run=tmp_path, round_bf16=True, checkpoint_every=500,
                     max_steps=None, budget=700.0, calibrate=40, eval_reserve=120.0, split="test", warmup_share=None,
                     **{k: None for k in job.TRAIN_FLAGS})
    tier = job.LARGE_BATCHES[-1]
    large = {"batch_size": tier["batch_size"], "lr": tier["lr"], "warmup_share": tier["warmup_share"],
             "speedup": 1.4, "reason": "fast"}
    job.start_worker(args, {"first_minute": {"seconds": 80.0, "gridcast": "auto", "batch": large}})
    cmd = seen["cmd"]
    assert cmd[cmd.index("--batch-size") + 1] == "256" and float(cmd[cmd.index("--lr") + 1]) == 4e-3
    assert float(cmd[cmd.index("--warmup-share") + 1]) == 1 / 13 and cmd[cmd.index("--budget") + 1] == "620.0"
    kept = {**large, "batch_size": None, "lr": None, "warmup_share": None}
    job.start_worker(args, {"first_minute": {"seconds": 80.0, "gridcast": "auto", "batch": kept}})
    assert not {"--batch-size", "--lr", "--warmup-share"} & set(seen["cmd"])


def test_the_marcher_is_the_fused_one_only_when_the_first_minute_found_the_two_agree():
    choose = _device_job_module().marcher_choice
    agree = {"pixels": 19_660_800, "hit_torch_only": 0, "hit_triton_only": 0, "max_abs_diff_m": 0.0}
    ok = {"errors": {}, "agreement": agree}
    assert choose(ok)["gridcast"] == "auto" and "agree" in choose(ok)["reason"]
    few = {"errors": {}, "agreement": {**agree, "hit_torch_only": 100, "hit_triton_only": 96, "max_abs_diff_m": 9e-4}}
    assert choose(few)["gridcast"] == "auto"                      # 196 flips: a share of 1.0e-5, 0.9 mm
    for bad, word in (({**agree, "hit_triton_only": 197}, "disagree"), ({**agree, "max_abs_diff_m": 2e-3}, "disagree"),
                      ({}, "did not run")):
        got = choose({"errors": {}, "agreement": bad})
        assert got["gridcast"] == "torch" and word in got["reason"], (bad, got)
    for stage in ("setup", "compile", "agreement"):
        got = choose({"errors": {stage: "RuntimeError: no kernel"}, "agreement": agree})
        assert got["gridcast"] == "torch" and stage in got["reason"] and "no kernel" in got["reason"]
    assert choose({"errors": {"poses": "cut"}, "agreement": agree})["gridcast"] == "auto"   # a later stage: no matter
    from hbeo.render.gridcast import RENDER_AHEAD                   # the largest march of the training
    render = {"triton": [{"batch": 512, "images_per_s": 9e4}, {"batch": RENDER_AHEAD, "error": "OutOfResources: x"}]}
    got = choose({"errors": {}, "agreement": agree, "render": render})
    assert got["gridcast"] == "torch" and f"batch {RENDER_AHEAD}" in got["reason"] and "OutOfResources" in got["reason"]
    render["triton"][1]["batch"] = 4 * RENDER_AHEAD                  # a batch the training never marches
    assert choose({"errors": {}, "agreement": agree, "render": render})["gridcast"] == "auto"
    assert choose({})["gridcast"] == "torch"


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="triton not installed")
def test_device_job_runs_the_first_minute_then_trains_on_the_marcher_it_chose_within_what_is_left(tmp_path, vox30_file):
    probe = subprocess.run([sys.executable, "-c", "import pyrender"], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": _device_like(tmp_path)})
    assert "not on the device" in probe.stderr                # the device-like path does hide those packages
    run, out = tmp_path / "run", tmp_path / "out"
    source = tmp_path / "source.json"                    # device_prepare.sh's: the device's copy has no .git
    source.write_text(json.dumps({"commit": "0123456789abcdef" * 2 + "01234567", "dirty": False}))
    # as on the device: its packages only, the fresh views streamed and ray-marched in torch (the full profile's)
    r = _job(run, out, "--first-minute", "240", "--budget", "400", "--calibrate", "2", "--eval-reserve", "20",
             "--max-steps", "4", "--dataset", "modelnet10-vox30", "--data", "stream", "--backend", "torch",
             pythonpath=[_device_like(tmp_path)], env={"HBEO_DEVICE_SOURCE": str(source)})
    assert r.returncode == 0, r.stdout + r.stderr + (run / "job.log").read_text()[-3000:]
    lease = json.loads((out / "lease.json").read_text())
    assert lease["train_data"] == "stream" and "not on the device" not in (run / "job.log").read_text()
    fm = lease["first_minute"]
    assert fm["exit"] == 0 and fm["report"]["stages_done"][:3] == ["setup", "compile", "agreement"]
    assert fm["report"]["setup"]["cpu_check"] and fm["gridcast"] == "auto"      # the interpreter: bit-equal
    assert fm["batch"]["batch_size"] is None and fm["batch"]["reason"]          # the ci profile: not the rule's
    assert 0 < fm["seconds"] < 240 and "bench_gpu_first_minute.py" in fm["command"]
    assert abs(lease["budget"]["seconds"] - (400 - fm["seconds"])) < 0.2    # the worker's budget: what was left
    assert len(list(out.iterdir())) <= 8 and not (out / "first_minute.json").exists()   # inside lease.json
    # what came back lands: checked, put in a run folder, scored again on this CPU (the same CPU: identical)
    land = _script_module("device_land")
    landed = land.land(out, tmp_path / "landed", per_class=1)
    assert (landed / "model.hbeo").read_bytes() == (run / "model.hbeo").read_bytes()
    re = json.loads((landed / "rescore_cpu.json").read_text())
    assert re["n_queries"] == 10 and re["class_differs"] == 0 and re["pose_max_abs_diff_deg"] == 0
    assert re["iou_max_abs_diff"] == re["edt_max_rel_diff"] == 0
    md = (landed / "REPRODUCTION.md").read_text()
    assert "stream data" in md and "marcher `auto`" in md and "| class mean accuracy | 30 / 30 |" in md
    assert "- Batch by the first minute's rule: the profile's: " in md and ", peak learning rate" in md
    assert lease["source"]["commit"].startswith("0123456789") and "- Code: commit `0123456789`, clean." in md
    assert json.loads((landed / "first_minute.json").read_text()) == fm["report"]
    assert (landed / "train_model" / "train_log.csv").exists()
    cpu = json.loads((landed / "eval_hbeo_3dof_cpu.json").read_text())
    assert cpu["n_queries"] == 10 and cpu["request"]["per_class"] == 1 and cpu["request"]["device"] == "cpu"
    assert lease["model_final"] and lease["steps"] == 4 and lease["images_seen"] == 4 * lease["batch_size"]
    # a lease whose last call was cut during the evaluation: the model came back final, its evaluation did not
    import shutil
    cut_short = tmp_path / "cut_short"
    shutil.copytree(out, cut_short)
    (cut_short / "eval_hbeo_3dof.json").unlink()
    (cut_short / "lease.json").write_text(json.dumps({**lease, "status": "running"}))
    with pytest.raises(land.LandError, match="--evaluate-here"):
        land.check(cut_short)
    here = land.land(cut_short, tmp_path / "landed_here", evaluate=True)        # evaluated on this CPU instead
    ev = json.loads((here / "eval_hbeo_3dof.json").read_text())
    gpu = json.loads((out / "eval_hbeo_3dof.json").read_text())
    assert ev["request"] == gpu["request"] and ev["per_query"]["pred"] == gpu["per_query"]["pred"]
    assert json.loads((here / "lease.json").read_text())["evaluated_here"].startswith("cpu: ")
    md = (here / "REPRODUCTION.md").read_text()
    assert "evaluated here" in md and "no evaluation came back" in md and "| class mean accuracy | 30 / 30 |" in md
    assert not (here / "rescore_cpu.json").exists()
    again = _job(run, tmp_path / "out2", "--first-minute", "240")        # finished: no second benchmark
    assert again.returncode == 0 and "first minute" not in again.stdout
    cut = _job(tmp_path / "run2", tmp_path / "out3", "--first-minute", "3", "--max-steps", "2", "--wait", "0")
    lease = json.loads((tmp_path / "out3" / "lease.json").read_text())       # cut short: what it had, torch
    assert lease["first_minute"]["exit"] == "timeout" and lease["first_minute"]["gridcast"] == "torch", lease
    assert cut.returncode in (0, 3)
    if cut.returncode == 3:                              # the worker it left running
        _kill_worker(tmp_path / "run2")


def test_device_land_lands_nothing_that_did_not_come_back_whole(tmp_path, capsys):
    land = _script_module("device_land")
    blob = os.urandom(40_000)
    packed = gzip.compress(blob)
    sha = hashlib.sha256(blob).hexdigest()

    def came_back(name, lease=None, parts=(packed[:20_000], packed[20_000:]), model_sha=sha[:16]):
        src = tmp_path / name
        src.mkdir()
        (src / "lease.json").write_text(json.dumps({"status": "done", "split": "test", "model_sha256": sha,
                                                    "model_bytes": len(blob), **(lease or {})}))
        for i, part in enumerate(parts):
            (src / f"model.hbeo.gz.part{i:02d}").write_bytes(part)
        (src / "eval_hbeo_3dof.json").write_text(json.dumps({"request": {"model_sha256": model_sha}, "n_queries": 2,
                                                             "per_query": {"pred": ["bed", "sofa"]}}))
        return src

    assert land.check(came_back("whole"))["model_bytes"] == blob
    for name, kw, words in (("running", {"lease": {"status": "running"}}, ("lease.json", "'running'")),
                            ("val", {"lease": {"split": "val"}}, ("lease.json", "val split")),
                            ("other", {"lease": {"model_sha256": "0" * 64}}, ("model.hbeo.gz.part*", "SHA-256")),
                            ("cut", {"parts": (packed[:20_000],)}, ("model.hbeo.gz.part*", "do not gunzip")),
                            ("none", {"parts": ()}, ("no model.hbeo.gz.part*",)),
                            ("scored", {"model_sha": "f" * 16}, ("eval_hbeo_3dof.json", "scored the model"))):
        src = came_back(name, **kw)
        with pytest.raises(land.LandError) as err:
            land.check(src)
        assert str(src) in str(err.value) and all(w in str(err.value) for w in words), (name, str(err.value))
    (tmp_path / "bad" ).mkdir()
    (tmp_path / "bad" / "lease.json").write_text("{not json")
    assert land.main([str(tmp_path / "bad"), "--run", str(tmp_path / "run")]) == 1
    assert "lease.json: not readable JSON" in capsys.readouterr().err and not (tmp_path / "run").exists()


def test_device_job_refuses_bad_training_flags(tmp_path):
    for flags, word in ((("--epochs", "0"), "--epochs"), (("--first-minute", "-1"), "--first-minute"), (("--seed", "-1"), "--seed"),
                        (("--class-balance", "some"), "--class-balance"), (("--split", "train"), "--split"),
                        (("--loss-weights", "1,1"), "--loss-weights"), (("--fc", "64,0,64"), "--fc")):
        r = _job(tmp_path / "run", tmp_path / "out", *flags)
        assert r.returncode == 2 and word in r.stderr, (flags, r.stderr)


def test_device_tree_slim_leaves_the_committed_results_and_history_behind_and_restore_tracks_them_again(tmp_path):
    import shutil
    repo = tmp_path / "repo"
    (repo / "maintainer").mkdir(parents=True)
    shutil.copy(ROOT / "maintainer" / "device_tree.sh", repo / "maintainer")
    # results/b/model.hbeo un-ignored by .gitignore, as results/quick-procedural/model.hbeo: an exclude line alone
    # would not keep it from travelling
    for f in ("results/a/model.hbeo", "results/b/model.hbeo", "results/a/table.csv", "results/a/01_x.ipynb",
              "results/README.md", "docs/history/log.md", "docs/scale.md", "notebooks/01_x.ipynb", "hbeo/x.py",
              ".gitignore"):
        (repo / f).parent.mkdir(parents=True, exist_ok=True)
        (repo / f).write_text("results/b/*.hbeo\n!results/b/model.hbeo\n" if f == ".gitignore" else f)
    git = lambda *a: subprocess.run(["git", "-C", str(repo), *a], capture_output=True, text=True, check=True).stdout
    git("init", "-q")
    git("-c", "user.name=t", "-c", "user.email=t@t", "add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "x")
    run = lambda cmd: subprocess.run(["bash", str(repo / "maintainer" / "device_tree.sh"), cmd], capture_output=True, text=True)
    travels = lambda: set(git("ls-files").split()) | set(git("ls-files", "-o", "--exclude-standard").split())
    before = travels()
    slim = run("slim")
    assert slim.returncode == 0 and "to travel now: 0 MiB" in slim.stdout, slim.stdout + slim.stderr
    assert travels() == before - {"results/a/model.hbeo", "results/b/model.hbeo", "results/a/01_x.ipynb",
                                  "results/a/table.csv", "docs/history/log.md"}
    assert (repo / ".device-aside/results/a/model.hbeo").read_text() == "results/a/model.hbeo"   # kept aside
    assert run("slim").returncode == 2                              # twice: refused
    commit = subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "y"],
                            capture_output=True, text=True)           # it would delete the results: refused
    assert commit.returncode != 0 and "device_tree.sh restore" in commit.stderr
    assert run("restore").returncode == 0
    assert not (repo / ".git/hooks/pre-commit").exists()
    over = subprocess.run(["bash", str(repo / "maintainer" / "device_tree.sh"), "slim"], capture_output=True,
                          text=True, env={**os.environ, "LIMIT_MIB": "0"})   # what is left still too big: said
    assert over.returncode == 3 and "still over 0 MiB" in over.stderr
    assert run("restore").returncode == 0
    assert travels() == before and git("status", "--porcelain") == "" and not (repo / ".device-aside").exists()
    assert (repo / "results/b/model.hbeo").read_text() == "results/b/model.hbeo"
    assert "model.hbeo" not in (repo / ".git/info/exclude").read_text()
    git("rm", "-q", "--cached", "hbeo/x.py")                        # staged changes: slim refuses
    assert run("slim").returncode == 2
    git("reset", "-q", "hbeo/x.py")
    own = repo / ".git" / "hooks" / "pre-commit"                   # the repository's own hook: left as it is
    own.parent.mkdir(exist_ok=True)
    own.write_text("#!/bin/sh\nexit 0\n")
    assert run("slim").returncode == 0 and run("restore").returncode == 0
    assert own.read_text() == "#!/bin/sh\nexit 0\n"
