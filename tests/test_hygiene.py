"""What the repository holds and what cleaning it may delete: no large file outside results/, no checkpoint
anywhere, and ``make clean-results`` never deletes a committed run."""
from __future__ import annotations

import fnmatch
import shutil
import subprocess
from pathlib import PurePosixPath, Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: the largest tracked file outside results/ (run products: the committed runs' notebooks, model files)
MAX_BYTES = 10 ** 6
#: names of training checkpoints, which are never committed (a model is committed as its model file)
CHECKPOINT_NAMES = ("*.pt", "*.ckpt", "*.pth", "checkpoint*")

needs_git = pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                               reason="not a git checkout")
needs_make = pytest.mark.skipif(shutil.which("make") is None or shutil.which("git") is None, reason="no make or git")


def _git(*args, cwd=ROOT, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, **kw)


def tracked_sizes(root: Path = ROOT) -> dict[str, int]:
    """Every tracked path (the index: what a commit holds, not the working tree's edits) -> its size in bytes."""
    staged = _git("ls-files", "-z", "--stage", cwd=root).stdout.split(b"\0")
    entries = [e.decode().split("\t", 1) for e in staged if e]
    blobs = {path: meta.split()[1] for meta, path in entries if meta.split()[0] != "160000"}   # not submodules
    out = _git("cat-file", "--batch-check=%(objectname) %(objectsize)", cwd=root,
               input="\n".join(blobs.values()).encode()).stdout.decode().split("\n")
    size = dict(line.split() for line in out if line)
    return {path: int(size[sha]) for path, sha in blobs.items()}


def is_checkpoint(path: str) -> bool:
    name = PurePosixPath(path).name
    return any(fnmatch.fnmatch(name.lower(), pattern) for pattern in CHECKPOINT_NAMES)


@needs_git
def test_no_large_file_outside_results():
    big = {p: n for p, n in tracked_sizes().items() if n > MAX_BYTES and not p.startswith("results/")}
    assert not big, "tracked files over 1 MB outside results/ (keep data out of the repository, or in results/):\n" \
        + "\n".join(f"{p}: {n:,} bytes" for p, n in sorted(big.items(), key=lambda kv: -kv[1]))


@needs_git
def test_no_checkpoint_is_tracked():
    found = sorted(p for p in tracked_sizes() if is_checkpoint(p))
    assert not found, "tracked training checkpoints (commit the model file, not its checkpoints):\n" + "\n".join(found)


def test_the_checkpoint_names_are_recognized():
    assert all(is_checkpoint(p) for p in ("results/r/train_model/checkpoint.pt", "a/checkpoint-staged.pt",
                                          "x/model.ckpt", "x/weights.PTH", "checkpoint"))
    assert not any(is_checkpoint(p) for p in ("results/r/model.hbeo", "hbeo/model/loop.py", "tests/resume_job.py",
                                              "docs/script.ptx"))


# ------------------------------------------------------------------ make clean-results

REF = "results/cpu-modelnet10-vox30"      # a committed run
NEW = "results/ci-procedural"             # a run made here
TRACKED = ["results/README.md", f"{REF}/manifest.json", f"{REF}/train_model/train_log.csv", f"{REF}/model.hbeo",
           "hbeo.txt"]
UNTRACKED = [f"{NEW}/manifest.json", f"{NEW}/render_train/shard-000.npz", f"{REF}/render_test/shard-000.npz",
             f"{REF}/train_model/checkpoint.pt", f"{REF}/grids_train.npz", f"{REF}/notes.txt", "results/loose.csv"]


def _repo(tmp_path: Path) -> Path:
    """A git checkout with the project's Makefile, a committed run and generated files (some ignored)."""
    repo = tmp_path / "repo"
    repo.mkdir()
    shutil.copy(ROOT / "Makefile", repo / "Makefile")
    (repo / ".gitignore").write_text("results/*/render_*/\nresults/*/train_*/*\n!results/*/train_*/train_log.csv\n"
                                     f"results/*/grids_*.npz\n{NEW}/\n")
    for p in TRACKED + UNTRACKED + ["notes-outside.txt"]:
        (repo / p).parent.mkdir(parents=True, exist_ok=True)
        (repo / p).write_text(p)
    _git("init", "-q", cwd=repo)
    _git("add", "Makefile", ".gitignore", *TRACKED, cwd=repo)
    _git("-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-q", "-m", "runs", cwd=repo)
    return repo


def _make(repo: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-s", "clean-results", *args], cwd=repo, capture_output=True, text=True)


def _files(repo: Path) -> set[str]:
    return {p.relative_to(repo).as_posix() for p in repo.rglob("*") if p.is_file() and ".git" not in p.parts}


@needs_make
def test_clean_results_deletes_only_untracked_files_under_results(tmp_path):
    repo = _repo(tmp_path)
    everything = _files(repo)
    dry = _make(repo, "DRY=1")
    assert dry.returncode == 0 and _files(repo) == everything, dry.stderr      # DRY=1 deletes nothing
    assert f"{NEW}/\n" in dry.stdout and f"{REF}/train_model/checkpoint.pt" in dry.stdout, dry.stdout
    assert "model.hbeo" not in dry.stdout and "train_log.csv" not in dry.stdout, dry.stdout
    done = _make(repo)
    assert done.returncode == 0, done.stderr
    left = _files(repo)
    assert left == {"Makefile", ".gitignore", "notes-outside.txt", *TRACKED}, left   # the committed run as committed
    assert not (repo / NEW).exists()                                                 # the run made here is gone
    assert _git("status", "--porcelain", "--", "results", cwd=repo).stdout == b""


@needs_make
def test_clean_results_refuses_where_git_cannot_tell_the_runs_apart(tmp_path):
    plain = tmp_path / "copy"                       # an unpacked copy: no .git
    (plain / REF).mkdir(parents=True)
    shutil.copy(ROOT / "Makefile", plain / "Makefile")
    (plain / REF / "model.hbeo").write_text("weights")
    done = _make(plain)
    assert done.returncode != 0 and "not the top of a git checkout" in done.stderr and "nothing deleted" in done.stderr
    assert (plain / REF / "model.hbeo").exists()
    outer = _repo(tmp_path)                         # a copy inside another checkout: its runs are untracked there
    inner = outer / "vendored"
    (inner / REF).mkdir(parents=True)
    shutil.copy(ROOT / "Makefile", inner / "Makefile")
    (inner / REF / "model.hbeo").write_text("weights")
    done = _make(inner)
    assert done.returncode != 0 and "nothing deleted" in done.stderr
    assert (inner / REF / "model.hbeo").exists()


@needs_make
@pytest.mark.parametrize("seed, folder", [("01", "-seed1"), ("1", "-seed1"), ("00", ""), ("08", "-seed8")])
def test_make_reads_the_seed_as_a_number_as_reproduce_does(seed, folder):
    """``make reproduce SEED=01`` writes where ``make book SEED=01`` reads (reproduce takes the seed as a number)."""
    done = subprocess.run(["make", "-n", "reproduce", "book", f"SEED={seed}", "VENV=/nonexistent-venv"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert [ln for ln in lines if " book " in ln][0].endswith(f"results/quick-procedural{folder}")
    want = f" --seed {int(seed)}" if int(seed) else " --fresh"
    assert [ln for ln in lines if " reproduce " in ln][0].endswith(want)


@needs_make
@pytest.mark.parametrize("seed", ["abc", "-1", ""])
def test_make_refuses_a_seed_that_is_not_a_whole_number(seed):
    done = subprocess.run(["make", "-n", "book", f"SEED={seed}", "VENV=/nonexistent-venv"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode != 0 and "SEED must be a whole number" in done.stderr
