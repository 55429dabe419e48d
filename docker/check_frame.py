"""Host-side helpers of ``docker/check.sh``: a test frame, the reference answer, latencies.

    python docker/check_frame.py port                               # a free TCP port on 127.0.0.1
    python docker/check_frame.py generate DIR                       # DIR/gray.png, DIR/sparse.npy
    python docker/check_frame.py compare MODEL DIR RESULT --threads N --url URL
    python docker/check_frame.py latency URL DIR --repeat N         # JSON: round trip, inference

``compare`` runs MODEL on the host with onnxruntime (``OnnxModel`` + ``sdcnet.pipeline
.complete``, as the service does) and holds ``sdc-client infer``'s ``RESULT/depth.npy`` and
``RESULT/mask.png`` to it, at the budget the service at URL chose for its CPU (``GET /model``'s
``frame_budget``: its working pixels and share, ``sdcnet.frame_budget``). The same graph on
the same CPU with the same thread count gives the same bits when the onnxruntime versions
match; a different onnxruntime (the image installs its newest release, the host's may be
older) may pick other kernels, so the check allows float noise: depth within 1e-4 m + 1e-5
relative where both masks agree, and mask differences only on pixels whose probability is
within 1e-4 of the 0.5 threshold. It says which case it saw.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np

#: Tolerances, see the module docstring.
DEPTH_ATOL_M, DEPTH_RTOL, PROBABILITY_MARGIN = 1e-4, 1e-5, 1e-4


def cmd_port(args: argparse.Namespace) -> int:
    """Print a TCP port that is free on 127.0.0.1 now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        print(s.getsockname()[1])
    return 0


def cmd_generate(args: argparse.Namespace) -> int:
    """One frame of the project's generator (paper camera and LIDAR, 1024 x 1024)."""
    from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample

    config = GenerateConfig(models=1, views=1, seed=args.seed)
    sample = make_sample(config, build_spacecraft(config, 0), 0, 0, "test")
    args.dir.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.dir / "gray.png"), sample.gray):
        raise SystemExit(f"cannot write {args.dir / 'gray.png'}")
    np.save(args.dir / "sparse.npy", sample.sparse.astype(np.float32), allow_pickle=False)
    print(
        f"frame {sample.gray.shape[1]} x {sample.gray.shape[0]}, "
        f"{sample.meta['returns']} LIDAR returns, {sample.meta['foreground_px']} spacecraft px"
    )
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Exit 0 when the service's answer equals the host's onnxruntime run (see above)."""
    import onnxruntime

    from sdcnet.client.api import Client
    from sdcnet.pipeline import complete
    from sdcnet.runtime.onnx import OnnxModel

    gray = cv2.imread(str(args.dir / "gray.png"), cv2.IMREAD_UNCHANGED)
    sparse = np.load(args.dir / "sparse.npy", allow_pickle=False)
    model = OnnxModel(args.model, provider="cpu", threads=args.threads)
    K = model.info.intrinsics.scaled(gray.shape[1], gray.shape[0])  # what the service defaults to
    with Client(args.url, retries=0) as client:
        budget = client.model()["frame_budget"]  # what the service chose for its CPU
    ref = complete(
        model.run,
        gray,
        sparse,
        K.fx,
        model.stride,
        budget["work_pixels"],
        frame_share=budget["frame_share"],
    )

    depth = np.load(args.result / "depth.npy", allow_pickle=False)
    mask = cv2.imread(str(args.result / "mask.png"), cv2.IMREAD_UNCHANGED) > 0
    if depth.shape != ref.depth.shape or depth.dtype != np.float32 or mask.shape != ref.mask.shape:
        print(
            f"compare: answer {depth.dtype} {depth.shape} mask {mask.shape}, expected float32 "
            f"{ref.depth.shape}",
            file=sys.stderr,
        )
        return 1
    if not ref.mask.any():
        print(
            "compare: the model predicts no foreground on this frame: nothing to compare",
            file=sys.stderr,
        )
        return 1

    where = (
        f"host onnxruntime {onnxruntime.__version__}, {model.threads} threads, the service's "
        f"{budget['frame_share']:g} of the frame budget"
    )
    if np.array_equal(depth, ref.depth) and np.array_equal(mask, ref.mask):
        print(
            f"compare: depth and mask bit-identical to the direct run ({where}); "
            f"{int(ref.mask.sum())} mask px"
        )
        return 0

    mask_diff = mask != ref.mask
    near_threshold = np.abs(ref.probability - 0.5) <= PROBABILITY_MARGIN
    both = mask & ref.mask
    error = np.abs(depth[both].astype(np.float64) - ref.depth[both])
    allowed = DEPTH_ATOL_M + DEPTH_RTOL * np.abs(ref.depth[both])
    report = (
        f"max |depth diff| {error.max(initial=0.0):.3g} m over {int(both.sum())} px, "
        f"{int(mask_diff.sum())} mask px differ ({int((mask_diff & ~near_threshold).sum())} "
        f"away from the threshold); {where}"
    )
    if (mask_diff & ~near_threshold).any() or (error > allowed).any():
        print(f"compare: MISMATCH: {report}", file=sys.stderr)
        return 1
    print(f"compare: equal within float tolerance, not bit-identical: {report}")
    return 0


def cmd_latency(args: argparse.Namespace) -> int:
    """Median round trip and server-side inference time of ``repeat`` requests after one
    warm-up (the first request pays for onnxruntime's lazy initialisation)."""
    from sdcnet.client.api import Client

    gray, sparse = args.dir / "gray.png", args.dir / "sparse.npy"
    round_trip, inference = [], []
    with Client(args.url, timeout_s=120, retries=0) as client:
        client.complete(gray, sparse)
        for _ in range(args.repeat):
            result = client.complete(gray, sparse)
            round_trip.append(result.latency_s * 1e3)
            inference.append(result.timings_ms.get("inference_ms", float("nan")))
    print(
        json.dumps(
            {
                "round_trip_ms": round(statistics.median(round_trip), 1),
                "inference_ms": round(statistics.median(inference), 1),
                "provider": result.provider,
                "requests": args.repeat,
            }
        )
    )
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("port").set_defaults(run=cmd_port)
    gen = sub.add_parser("generate")
    gen.add_argument("dir", type=Path)
    gen.add_argument("--seed", type=int, default=0)
    gen.set_defaults(run=cmd_generate)
    cmp = sub.add_parser("compare")
    cmp.add_argument("model", type=Path)
    cmp.add_argument("dir", type=Path)
    cmp.add_argument("result", type=Path)
    cmp.add_argument("--threads", type=int, default=2)
    cmp.add_argument("--url", required=True, help="the service that answered")
    cmp.set_defaults(run=cmd_compare)
    lat = sub.add_parser("latency")
    lat.add_argument("url")
    lat.add_argument("dir", type=Path)
    lat.add_argument("--repeat", type=int, default=5)
    lat.set_defaults(run=cmd_latency)
    return p


if __name__ == "__main__":
    arguments = parser().parse_args()
    sys.exit(arguments.run(arguments))
