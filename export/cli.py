"""``sdc-export``: checkpoint -> self-contained ONNX model, with the parity check.

The parity frames are rendered on the spot by the data generator (seeded), so the check needs
no dataset on disk. The graph is written next to ``--out`` under a temporary name and takes
its place only once the check has passed: a failed check leaves ``--out`` as it was (the
shipped model, say) and exits 1 with the figures.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

from sdcnet.cli import FILE_AND_VALUE_ERRORS, add_debug_flag, run_command
from sdcnet.dataset_format import SampleStore
from sdcnet.export.onnx_export import (
    MAX_DEPTH_ERROR_M,
    MAX_SIGMA_ERROR,
    MIN_MASK_AGREEMENT,
    Frame,
    export_checked,
    network_metadata_props,
)
from sdcnet.export.variants import to_fp16, to_int8
from sdcnet.training.checkpoint import load_checkpoint
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample


def parity_frames(seed: int, count: int = 2) -> list[Frame]:
    """``count`` 1024 x 1024 frames of procedural spacecraft (gray, sparse, fx), rendered now."""
    config = GenerateConfig(models=count, views=1, seed=seed, split=(count, 0, 0))
    frames = []
    for m in range(count):
        sample = make_sample(config, build_spacecraft(config, m), m, 0, "parity")
        frames.append((sample.gray, sample.sparse, sample.meta["intrinsics"]["fx"]))
    return frames


def weights_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-export", description=__doc__)
    p.add_argument("--checkpoint", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path, help="ONNX file to write")
    p.add_argument(
        "--metrics", type=Path, help="JSON of `sdc-eval evaluate --out`: headline metrics to embed"
    )
    p.add_argument(
        "--parity-seed", type=int, default=2024, help="seed of the rendered parity frames"
    )
    p.add_argument(
        "--variants",
        nargs="*",
        default=[],
        choices=["fp16", "int8"],
        help="also write OUT with .fp16.onnx / .int8.onnx suffixes",
    )
    p.add_argument(
        "--calibration-data",
        type=Path,
        help="dataset whose train split calibrates INT8 (default: 32 rendered frames)",
    )
    add_debug_flag(p)
    return p


def export(args: argparse.Namespace) -> int:
    """The export, its parity check and the variants; 1 when the check fails."""
    model, state = load_checkpoint(args.checkpoint)
    metrics = {}
    if args.metrics:
        report = json.loads(args.metrics.read_text())
        metrics = {
            "split": report["split"],
            "images": report["images"],
            **next(iter(report["results"].values())),
        }
    variant = state.get("train_config", {}).get("variant", "model")
    version = f"sdcnet-{variant}-{weights_digest(args.checkpoint)}"
    extra = {
        "checkpoint_sha256_12": weights_digest(args.checkpoint),
        "train_command": state.get("train_config", {}).get("command", ""),
        "dataset_command": state.get("dataset", {}).get("command", ""),
    }
    metadata = network_metadata_props(model, version, metrics, extra)
    cases = export_checked(model, args.out, metadata, parity_frames(args.parity_seed))
    print(
        f"{version}: parity, onnxruntime CPU vs PyTorch (bounds: depth <= "
        f"{MAX_DEPTH_ERROR_M * 1000:.1f} mm on the foreground, sigma <= "
        f"{100 * MAX_SIGMA_ERROR:.1f} % where both masks agree around the pixel, mask agreement "
        f">= {100 * MIN_MASK_AGREEMENT:.2f} %):"
    )
    for c in cases:
        print(
            f"  {c.size:4d} px, batch {c.batch}: max |depth diff| "
            f"{c.max_depth_error_m * 1000:.4f} mm over {c.compared_px} foreground px, "
            f"sigma {100 * c.max_sigma_error:.4f} %, "
            f"mask agreement {100 * c.mask_agreement:.4f} %  "
            f"{'ok' if c.passed else 'FAILED'}"
        )
    if not all(c.passed for c in cases):
        print(
            f"sdc-export: parity check FAILED: the ONNX model does not reproduce PyTorch; "
            f"{args.out} left as it was",
            file=sys.stderr,
        )
        return 1
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")
    for name in args.variants:
        target = args.out.with_suffix(f".{name}.onnx")
        if name == "fp16":
            to_fp16(args.out, target)
        else:
            frames = calibration_frames(args.calibration_data)
            to_int8(args.out, target, frames, model.config.stride, model.float_modules())
        print(f"wrote {target} ({target.stat().st_size / 1e6:.2f} MB)")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-export", lambda: export(args), FILE_AND_VALUE_ERRORS, args.debug)


def calibration_frames(data: Path | None, count: int = 32) -> list:
    """INT8 calibration frames: spread over a dataset's train split, or rendered (seeded)."""
    if data is None:
        return parity_frames(seed=4096, count=count)
    store = SampleStore(data)
    samples = map(store.load, store.split("train", count))
    return [(s.gray, s.sparse, s.meta["intrinsics"]["fx"]) for s in samples]


if __name__ == "__main__":
    sys.exit(main())
