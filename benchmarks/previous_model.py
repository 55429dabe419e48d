"""The previous shipped model as its own service ran it, on today's frames: its answers on disk.

    python -m benchmarks.previous_model --commit e6a386e --data data/paper --split test \\
        --limit 288 --out runs/previous/paper
    python -m benchmarks.previous_model --commit e6a386e --data data/robustness --out runs/previous

A model of another design cannot run in today's pipeline, so this installs the package as it
was at ``--commit`` (``git archive``, then ``pip install --target``, once) and runs that
version's own pipeline and model in a subprocess: the crop resampled to the model's focal
length as its service did (``zoom``, up to 4x) from each frame's true intrinsics, as a user who
sends them gets. Each frame's depth, mask and milliseconds go to ``OUT/<id>.npz``; ``sdc-eval
evaluate / real / robustness --answers "previous model=OUT"`` score them like any method.
With a folder of datasets (``data/robustness``), one ``OUT/<dataset>`` per dataset.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import sysconfig
import tarfile
import tempfile
from pathlib import Path

from sdcnet.dataset_format import SampleStore

ROOT = Path(__file__).resolve().parents[1]

#: Runs under the previous version's package: its pipeline, model, zoom rule and sample reader.
RUNNER = """
import json, sys, time
from pathlib import Path
import numpy as np
from sdcnet.dataset_format import SampleStore
from sdcnet.pipeline import complete
from sdcnet.runtime import OnnxModel  # the previous version's module, not this checkout's package
from sdcnet.service.inference import pixel_scale

job = json.loads(sys.argv[1])
model = OnnxModel(job["model"], provider="cpu", threads=job["threads"], spin_wait=False)
store = SampleStore(job["data"])
wanted = set(job["ids"])
out = Path(job["out"])
out.mkdir(parents=True, exist_ok=True)
for record in (r for r in store.records if r["id"] in wanted):
    sample = store.load(record)
    H, W = sample.gray.shape
    fx = record["intrinsics"]["fx"]
    zoom = pixel_scale(model.info.intrinsics.fx, fx, W * H, 4096 * 4096)
    start = time.perf_counter()
    result = complete(model.run, sample.gray, sample.sparse, model.stride, zoom=zoom)
    ms = (time.perf_counter() - start) * 1e3
    np.savez_compressed(
        out / (record["id"] + ".npz"), depth=result.depth, mask=result.mask, milliseconds=ms
    )
    print(record["id"], f"{ms:.0f} ms", flush=True)
"""


def install(commit: str, where: Path) -> Path:
    """The package as it was at ``commit``, installed (once) under ``where``; returns the
    folder to put on PYTHONPATH."""
    site = where / commit / "site"
    if (site / "sdcnet" / "pipeline.py").exists():
        return site
    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / "src.tar"
        subprocess.run(
            ["git", "-C", str(ROOT), "archive", "--format=tar", "-o", str(archive), commit],
            check=True,
        )
        with tarfile.open(archive) as tar:
            tar.extractall(Path(tmp) / "src", filter="data")
        subprocess.run(
            [
                sys.executable,
                *("-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation"),
                *("--target", str(site), str(Path(tmp) / "src")),
            ],
            check=True,
        )
    return site


def run(site: Path, data: Path, ids: list[str], out: Path, threads: int) -> None:
    """The previous version's pipeline on frames ``ids`` of ``data``, answers into ``out``."""
    todo = [i for i in ids if not (out / f"{i}.npz").exists()]
    if not todo:
        return
    job = {
        "model": str((site / "sdcnet" / "models" / "sdcnet.onnx").resolve()),
        "data": str(data.resolve()),
        "ids": todo,
        "out": str(out.resolve()),
        "threads": threads,
    }
    # -S: no site module, so the editable install of this checkout (a meta-path finder that a
    # .pth file registers, ahead of PYTHONPATH) cannot shadow the previous version's sdcnet; the
    # third-party packages come from this environment's site-packages, named explicitly. Run
    # from the install folder: this checkout's own sdcnet/ must not be the working directory.
    packages = sysconfig.get_paths()["purelib"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site.resolve()), packages])}
    subprocess.run(
        [sys.executable, "-S", "-c", RUNNER, json.dumps(job)], env=env, cwd=site, check=True
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--commit", required=True, help="the version whose model and pipeline to run")
    p.add_argument("--data", required=True, type=Path, help="a dataset, or a folder of them")
    p.add_argument("--split", help="only this split (default: every frame)")
    p.add_argument("--limit", type=int, help="at most this many frames, evenly spread")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--install-dir", type=Path, default=ROOT / "runs" / "previous-src")
    args = p.parse_args(argv)

    site = install(args.commit, args.install_dir)
    single = (args.data / "dataset.json").exists()
    datasets = [args.data] if single else sorted(d for d in args.data.iterdir() if d.is_dir())
    for data in datasets:
        store = SampleStore(data)
        records = store.split(args.split, args.limit) if args.split else store.records
        out = args.out if single else args.out / data.name
        run(site, data, [r["id"] for r in records], out, args.threads)
        (out / "answers.json").write_text(
            json.dumps({"commit": args.commit, "data": str(data), "frames": len(records)})
        )
        print(f"{data}: {len(records)} frames answered by {args.commit} into {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
