"""The GPU campaign: one paper-scale Table I run that every lent GPU continues by a chunk.

A lent GPU machine has no network, Python 3.12 with torch but none of MuJoCo, MuJoCo Warp,
Warp or TorchRL, takes 64 MiB per call (the working tree included), 10 minutes per command and
15 minutes of device time per session. So the work splits in three:

``pack`` (here, once per change of code, libraries or data) writes ``.gpu-pack/carry/``: the
missing packages installed for Python 3.12 (``pip install --target``, Warp's tests and CPU
compiler left out), the run's objects built with 64^3 SDF grids plus their settled initial
states, and Warp's CUDA kernel cache if an earlier chunk brought one back; all in one xz-packed
tar split into parts that each fit one call beside the working tree. It prints the device
calls to make: one per part, the last of them the chunk (``scripts/gpu-campaign.sh``):

    python scripts/gpu_campaign.py slim      # results/ (runs' checkpoints) out of the calls
    python scripts/gpu_campaign.py pack
    # device run, carry [.gpu-pack/carry/part-1]: bash scripts/gpu-campaign.sh stage
    # device run, carry [.gpu-pack/carry/part-2]: bash scripts/gpu-campaign.sh run
    python scripts/gpu_campaign.py collect <files_at of the last call>
    python scripts/gpu_campaign.py unslim    # before committing anything

Calls after the first must come within the machine's idle release (30 s), or the staged parts
are lost with it. ``collect`` puts the chunk's checkpoint, metrics and evaluation into
``results/gpu-table1-campaign/`` (committed: the next lent GPU continues from there) and keeps
the kernel cache for the next ``pack``.

``check`` runs the device side here, from the parts, with an override of the config (the CPU
backend, few envs): what the GPU will run, slowly (tests/test_gpu_campaign.py runs it without
the parts).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACK = ROOT / ".gpu-pack"
CARRY = PACK / "carry"
CAMPAIGN = ROOT / "results" / "gpu-table1-campaign"
RUN = CAMPAIGN / "run"
CONFIG = CAMPAIGN / "campaign.toml"
DATA = ".gpu-pack/data"
"""The campaign's data directory, relative to the repository root on both machines (it is in the
run's config.json, which a resumed run keeps)."""
CALL_LIMIT = 64 * 2**20
"""What one device call may carry, the working tree included (bytes)."""
MARGIN = 3 * 2**20
"""Kept free in each call: the tree grows by the committed checkpoint between pack and call."""

PYTHON = "3.12"
"""The GPU machines' Python (/opt/torch/.venv/bin/python3 there, with torch 2.11+cu130)."""
WHEELS = (
    "warp-lang==1.19.0", "mujoco-warp==4.0.0", "mujoco==4.0.0", "mujoco-core==4.0.0",
    "mujoco-studio==4.0.0", "glfw", "pyopengl", "etils", "importlib_resources",
    "torchrl==0.14.1", "tensordict==0.14.3", "pyvers", "hoptorch", "orjson",
    "importlib_metadata",
)
"""What the GPU machines lack for `trainer run --backend warp` (their image holds numpy, scipy,
h5py, click, tqdm, matplotlib, pillow, tensorboard, absl-py, cloudpickle, packaging, fsspec,
typing-extensions and zipp: /work/.library/device/KINDS.md)."""
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64",
             "manylinux2014_x86_64", "manylinux1_x86_64")
DROP = ("warp/tests", "warp/examples", "warp/bin/warp-clang.so", "mujoco_warp/test_data",
        "mujoco/studio", "benchmarks", "sota-check", "sota-implementations", "scripts", "bin")
"""Not needed to train on a GPU: Warp's tests and examples, its CPU kernel compiler (loaded only
if present), MuJoCo Warp's test models, MuJoCo's studio, TorchRL's example scripts, launchers."""


def run(cmd: list[str], **kwargs) -> None:  # noqa: ANN003
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, **kwargs)


def tree_bytes(root: Path = ROOT) -> int:
    """What the working tree sends with each device call: tracked and untracked-not-ignored
    files."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=root, check=True, capture_output=True,
    ).stdout.decode()
    return sum((root / p).stat().st_size for p in out.split("\0") if p and (root / p).is_file())


SLIM_BLOCK = ("# gpu_campaign slim: results/ stays here (scripts/gpu_campaign.py unslim)\n"
              "/results/*\n!/results/gpu-table1-campaign/\n# end gpu_campaign slim\n")
"""The lines ``slim`` adds to the repository's own exclude file (never to .gitignore)."""


def git(root: Path, *args: str, stdin: str | None = None) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True,
                          input=stdin).stdout


def exclude_file(root: Path) -> Path:
    """The repository's own exclude file (``.git/info/exclude``, or a worktree's)."""
    return root / git(root, "rev-parse", "--git-path", "info/exclude").strip()


def slim(root: Path = ROOT) -> None:
    """Keep results/ (the runs' checkpoints: ~200 MB by 2026-11-29) out of what a device call
    carries, the campaign's own folder excepted: its files leave the index (not the disk) and
    the repository's exclude file ignores them. Nothing is committed; ``unslim`` puts the index
    back. Refuses while changes are staged, so that ``unslim`` loses none."""
    exclude = exclude_file(root)
    text = exclude.read_text() if exclude.is_file() else ""
    if SLIM_BLOCK in text:
        print(f"already slim: the tree a device call carries is {tree_bytes(root) / 2**20:.1f} MiB")
        return
    if subprocess.run(["git", "diff", "--cached", "--quiet"], cwd=root).returncode != 0:
        raise SystemExit("gpu_campaign: changes are staged: commit or unstage them before slim")
    names = [n for n in git(root, "ls-files", "results").splitlines()
             if not n.startswith("results/gpu-table1-campaign/")]
    if names:
        git(root, "rm", "-r", "--cached", "-q", "--pathspec-from-file=-", stdin="\n".join(names))
    exclude.parent.mkdir(parents=True, exist_ok=True)
    exclude.write_text(text + SLIM_BLOCK)
    print(f"the tree a device call carries: {tree_bytes(root) / 2**20:.1f} MiB ({len(names)} "
          "files of results/ out of the index); commit nothing until `python "
          "scripts/gpu_campaign.py unslim`")


def unslim(root: Path = ROOT) -> None:
    """Undo ``slim``: results/ back in the index as committed, the exclude lines removed."""
    git(root, "reset", "-q", "--", "results")
    exclude = exclude_file(root)
    if exclude.is_file():
        exclude.write_text(exclude.read_text().replace(SLIM_BLOCK, ""))
    print(f"results/ is tracked again; the tree: {tree_bytes(root) / 2**20:.1f} MiB")


def objects_and_config() -> tuple[list[str], dict]:
    """The campaign's objects and its config (campaign.toml as a dict)."""
    import tomllib

    cfg = tomllib.loads(CONFIG.read_text())
    return [n.strip() for n in cfg["objects"].split(",")], cfg


# --- pack ---------------------------------------------------------------------------------
def build_site(site: Path) -> None:
    """The missing packages, installed for the GPU machines' Python into ``site``."""
    if (site / ".complete").is_file():
        return
    shutil.rmtree(site, ignore_errors=True)
    platforms = [a for p in PLATFORMS for a in ("--platform", p)]
    run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-compile",
         "--only-binary=:all:", "--python-version", PYTHON, "--implementation", "cp",
         *platforms, "--target", str(site), *WHEELS])
    for rel in DROP:
        path = site / rel
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    (site / ".complete").write_text(" ".join(WHEELS))


def build_data(data: Path, names: list[str], source: Path, sdf_resolution: int) -> None:
    """The campaign's objects in ``data`` (built with ``sdf_resolution``^3 SDF grids, the
    geometry stages reused from ``source`` where it holds them), and their settled initial
    states under the campaign's physics; geomprep's stage files are left out."""
    sys.path.insert(0, str(ROOT))
    import dataclasses

    from geomprep import pipeline
    from geomprep.config import Config, SDFParams

    marker = data / ".complete"
    if marker.is_file() and marker.read_text() == f"{','.join(names)} {sdf_resolution}":
        return
    shutil.rmtree(data, ignore_errors=True)
    for part in ("raw", "interim"):
        for name in names:
            if (source / part / name).is_dir():
                shutil.copytree(source / part / name, data / part / name)
    cfg = dataclasses.replace(Config(data_dir=data), sdf=SDFParams(resolution=sdf_resolution))
    report = pipeline.build(cfg, pipeline.resolve_objects(cfg, names), jobs=1, progress=False)
    if report.failed:
        raise SystemExit(f"gpu_campaign: building {report.failed} failed")
    for stage_file in cfg.interim_dir.rglob("*.h5"):
        stage_file.unlink()
    settle_banks(data)
    marker.write_text(f"{','.join(names)} {sdf_resolution}")


def settle_banks(data: Path) -> None:
    """Build the campaign's settled initial states into ``data`` on the CPU (MuJoCo C, the same
    states the Warp backend would settle: the bank's key holds the physics, not the backend)."""
    sys.path.insert(0, str(ROOT))
    from trainer.config import load_env_config
    from trainer.tasks import make_env

    names, cfg = objects_and_config()
    env_keys = {k: v for k, v in cfg.items() if not isinstance(v, dict)
                and k not in ("num_envs", "backend", "device", "data_dir", "objects", "compile",
                              "representation")}
    sections = {k: v for k, v in cfg.items() if isinstance(v, dict) and k not in ("ppo", "run")}
    env_cfg = load_env_config(
        num_envs=len(names), objects=",".join(names), representation="bbox", data_dir=data,
        backend="cpu", device="cpu", **env_keys, **sections,
    )
    make_env(env_cfg, seed=0).close()


def pack(args: argparse.Namespace) -> None:
    names, _ = objects_and_config()
    build_site(PACK / "site")
    build_data(PACK / "data", names, args.source, args.sdf_resolution)
    budget = CALL_LIMIT - tree_bytes() - MARGIN
    if budget < 8 * 2**20:
        raise SystemExit(f"gpu_campaign: the working tree leaves only {budget >> 20} MiB per call: "
                         "`python scripts/gpu_campaign.py slim` keeps results/ out of it")
    shutil.rmtree(CARRY, ignore_errors=True)
    CARRY.mkdir(parents=True)
    blob = PACK / "payload.tar.xz"
    members = ["site", "data"] + (["kcache"] if (PACK / "kcache").is_dir() else [])
    start = time.time()
    tar = subprocess.Popen(["tar", "-C", str(PACK), "-cf", "-", *members],
                           stdout=subprocess.PIPE)
    with open(blob, "wb") as out:
        subprocess.run(["xz", f"-T{args.threads}", "-6", "-c"], stdin=tar.stdout, stdout=out,
                       check=True)
    if tar.wait() != 0:
        raise SystemExit("gpu_campaign: tar failed")
    size = blob.stat().st_size
    parts = []
    with open(blob, "rb") as handle:
        while chunk := handle.read(budget):
            path = CARRY / f"part-{len(parts) + 1}"
            path.write_bytes(chunk)
            parts.append({"name": path.name, "bytes": len(chunk),
                          "sha256": hashlib.sha256(chunk).hexdigest()})
    blob.unlink()
    manifest = {"parts": parts, "members": members, "packed": time.strftime("%Y-%m-%d %H:%M"),
                "commit": git_head()}
    (CARRY / "MANIFEST.json").write_text(json.dumps(manifest, indent=1))
    print(f"packed {', '.join(members)}: {size / 2**20:.1f} MiB in {len(parts)} part(s) of at "
          f"most {budget / 2**20:.1f} MiB ({time.time() - start:.0f} s)")
    print_plan(parts)


def print_plan(parts: list[dict]) -> None:
    print("device calls, one right after the other (the machine keeps staged parts 30 s):")
    for i, part in enumerate(parts, 1):
        verb = "run" if i == len(parts) else "stage"
        carry = [f".gpu-pack/carry/{part['name']}"] + (
            [".gpu-pack/carry/MANIFEST.json"] if verb == "run" else [])
        print(f"  {i}. carry {json.dumps(carry)}, timeout_s 600: "
              f"bash scripts/gpu-campaign.sh {verb}")
    print("then: python scripts/gpu_campaign.py collect <files_at>")


def git_head() -> str:
    return git(ROOT, "rev-parse", "--short", "HEAD").strip()


# --- collect ------------------------------------------------------------------------------
def collect(args: argparse.Namespace) -> None:
    """Bring a chunk's files home: the run's checkpoint, config and metrics into ``run/``, the
    evaluation and the chunk's log beside them, one row in chunks.csv; the kernel cache into
    ``.gpu-pack/kcache/`` for the next pack."""
    got = Path(args.files)
    campaign, pack_dir = args.results, args.pack_dir
    run = campaign / "run"
    missing = [n for n in ("last.pt", "chunk.tar") if not (got / n).is_file()]
    if missing:
        raise SystemExit(f"gpu_campaign: {got} lacks {', '.join(missing)}: the chunk did not "
                         "finish; its log (chunk.log, or the call's output) says why")
    with tempfile.TemporaryDirectory() as scratch:
        with tarfile.open(got / "chunk.tar") as tar:
            tar.extractall(scratch, filter="data")
        small = Path(scratch)
        chunk = json.loads((small / "chunk.json").read_text())
        (run / "checkpoints").mkdir(parents=True, exist_ok=True)
        shutil.copy(got / "last.pt", run / "checkpoints" / "last.pt")
        for name in ("metrics.csv", "config.json"):
            shutil.copy(small / name, run / name)
        if (small / "launches.csv").is_file():  # (a run's machines: since 2026-11-30)
            shutil.copy(small / "launches.csv", run / "launches.csv")
        if (small / "eval.json").is_file():
            shutil.copy(small / "eval.json", campaign / f"eval-iter{chunk['iteration']:04d}.json")
    if (got / "chunk.log").is_file():
        shutil.copy(got / "chunk.log", campaign / f"chunk-iter{chunk['iteration']:04d}.log")
    pieces = sorted(got.glob("kcache.tar.xz.*"))
    if pieces:
        shutil.rmtree(pack_dir / "kcache", ignore_errors=True)
        (pack_dir / "kcache").mkdir(parents=True)
        whole = pack_dir / "kcache.tar.xz"
        with open(whole, "wb") as out:
            for piece in pieces:
                out.write(piece.read_bytes())
        with tarfile.open(whole) as tar:
            tar.extractall(pack_dir / "kcache", filter="data")
        whole.unlink()
    rows = campaign / "chunks.csv"
    new = not rows.is_file()
    with open(rows, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(chunk))
        if new:
            writer.writeheader()
        writer.writerow(chunk)
    print(f"collected iteration {chunk['iteration']} ({chunk['env_steps']:,} env steps) into "
          f"{run}{'; the kernel cache into ' + str(pack_dir / 'kcache') if pieces else ''}: "
          "commit the results")


# --- check --------------------------------------------------------------------------------
def check(args: argparse.Namespace) -> None:
    """The device side on this machine: the parts staged one per 'call' into a scratch folder,
    then ``gpu-campaign.sh run`` on them (the unpacked data, a scratch run folder) with
    ``--python`` (an interpreter like the GPU's: Python 3.12 with torch) and ``CHECK_OVERRIDE``
    (the CPU backend, 10 envs, 2 iterations), into a local OUT."""
    work = Path(tempfile.mkdtemp(prefix="gpu-campaign-check-"))
    override = CHECK_OVERRIDE.format(data=work / "stage" / "data")
    env = dict(os.environ, GPU_CAMPAIGN_STAGE=str(work / "stage"), OUT=str(work / "out"),
               GPU_CAMPAIGN_PYTHON=args.python, GPU_CAMPAIGN_OVERRIDE=override,
               GPU_CAMPAIGN_RUN=str(work / "run"), GPU_CAMPAIGN_STEPS="80",
               GPU_CAMPAIGN_EPISODES="1")
    env.pop("PYTHONPATH", None)
    (work / "out").mkdir()
    start = time.time()
    for part in json.loads((CARRY / "MANIFEST.json").read_text())["parts"][:-1]:
        run(["bash", "scripts/gpu-campaign.sh", "stage", f".gpu-pack/carry/{part['name']}"],
            cwd=ROOT, env=env)
    run(["bash", "scripts/gpu-campaign.sh", "run"], cwd=ROOT, env=env)
    print(f"checked in {time.time() - start:.0f} s; out: {work / 'out'}")
    with tarfile.open(work / "out" / "chunk.tar") as tar:
        print(tar.extractfile("chunk.json").read().decode())


CHECK_OVERRIDE = """
backend = "cpu"
device = "cpu"
data_dir = "{data}"
num_envs = 10
max_steps = 20
[ppo]
frames_per_env = 4
minibatches = 1
min_minibatch = 1
epochs = 1
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="write .gpu-pack/carry/ and print the device calls")
    p.add_argument("--source", type=Path, default=ROOT / "data",
                   help="a data directory holding the objects' built stages (default: ./data)")
    p.add_argument("--sdf-resolution", type=int, default=64)
    p.add_argument("--threads", type=int, default=2, help="xz threads")
    p.set_defaults(func=pack)
    p = sub.add_parser("collect", help="put a chunk's returned files into results/")
    p.add_argument("files", help="the files_at folder of the chunk's device call")
    p.add_argument("--results", type=Path, default=CAMPAIGN,
                   help="the campaign's results folder [results/gpu-table1-campaign]")
    p.add_argument("--pack-dir", type=Path, default=PACK,
                   help="where the kernel cache goes for the next pack [.gpu-pack]")
    p.set_defaults(func=collect)
    p = sub.add_parser("slim", help="keep results/ (but the campaign's) out of device calls")
    p.set_defaults(func=lambda _: slim())
    p = sub.add_parser("unslim", help="undo slim: results/ tracked again as committed")
    p.set_defaults(func=lambda _: unslim())
    p = sub.add_parser("check", help="run the device side here, on the CPU")
    p.add_argument("--python", default=sys.executable,
                   help="a Python 3.12 with torch, as on the GPU machines")
    p.set_defaults(func=check)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
