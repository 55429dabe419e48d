"""What ``sdc-client pose`` writes for one frame, and the summary it prints.

``pose.json`` (the service's answer) and ``preview.png``: the gray image, and the target's
surface samples drawn at the estimated pose over it (coloured by distance), zoomed on the
spacecraft; an ambiguous answer adds its alternatives, in their own tiles.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.client.api import PoseAnswer
from sdcnet.visualize import draw_points, gray_bgr, labelled, montage, object_crop

POSE_OUTPUT_FILES = ("pose.json", "preview.png")
#: Alternatives of an ambiguous answer drawn in the preview, at most.
PREVIEW_ALTERNATIVES = 2


def answer_intrinsics(answer: PoseAnswer) -> Intrinsics:
    """The intrinsics the service used for this frame (pixels)."""
    completion = answer.answer["completion"]
    return Intrinsics(
        **completion["intrinsics"], width=completion["width"], height=completion["height"]
    )


def pose_preview(gray: np.ndarray, answer: PoseAnswer, points: np.ndarray, tile: int = 320):
    """BGR montage: gray | target drawn at the pose | ... at each alternative."""
    K = answer_intrinsics(answer)
    base = gray_bgr(gray)
    poses = [("pose", answer.pose)] + [
        (f"alternative {k + 1}", p)
        for k, p in enumerate(answer.alternatives[:PREVIEW_ALTERNATIVES])
    ]
    u, v = K.project(answer.pose.apply(points))
    inside = (u > -0.5) & (u < K.width - 0.5) & (v > -0.5) & (v < K.height - 0.5)
    mask = np.zeros(gray.shape, bool)
    mask[np.round(v[inside]).astype(int), np.round(u[inside]).astype(int)] = True
    window = object_crop(mask)
    radius = max(0, round((window[0].stop - window[0].start) / tile / 2))  # ~1 tile pixel
    drawn = [
        (name, draw_points(base, pose.apply(points), K, radius=radius)) for name, pose in poses
    ]
    a = answer.answer
    tiles = [labelled(base[window], f"gray, {a['completion']['returns']} returns")]
    tiles += [labelled(image[window], f"{name}, fit {a['fitness']:.2f}") for name, image in drawn]
    return montage([tiles], tile=tile)


def pose_summary(answer: PoseAnswer, target: str, url: str, written: list[Path]) -> str:
    """A one-screen report of one pose."""
    a, pose = answer.answer, answer.pose
    angle = np.degrees(2 * np.arccos(np.clip(pose.quaternion_wxyz()[0], -1, 1)))
    t = answer.timings_ms
    sigma = a.get("rotation_sigma_deg")
    cut = a.get("sigma_limit_m")
    limit = "no point" if cut is None else f"depth sigma <= {100 * cut:.1f} cm"
    lines = [
        f"pose of {target} at {url} ({'tracked' if a['tracked'] else 'from scratch'})",
        f"  t         [{pose.t[0]:.3f}, {pose.t[1]:.3f}, {pose.t[2]:.3f}] m "
        f"(range {np.linalg.norm(pose.t):.2f} m)",
        f"  rotation  quaternion_wxyz [{', '.join(f'{q:.5f}' for q in pose.quaternion_wxyz())}]"
        f" ({angle:.2f} deg from the camera's axes)",
        "  R         "
        + "\n            ".join("[" + ", ".join(f"{x:8.5f}" for x in row) + "]" for row in pose.R),
        f"  fit       fitness {a['fitness']:.3f}, rmse {a['rmse_m']:.3f} m, consistency "
        f"{a['consistency']:.2f}, returns rmse "
        + (f"{a['returns_rmse_m']:.3f} m" if a.get("returns_rmse_m") is not None else "n/a")
        + (f", sigma {sigma:.2f} deg" if sigma is not None else ""),
        f"  cloud     {a['completion']['point_count']:,} points registered ({limit}; "
        f"{a['completion']['uncertain_removed']:,} more uncertain left out)",
        "  verdict   " + a["verdict"] + (f" ({', '.join(a['reasons'])})" if a["reasons"] else ""),
        "  ambiguous "
        + (f"yes: {len(a['alternatives'])} alternatives" if a["ambiguous"] else "no"),
        f"  latency   {answer.latency_s * 1e3:.1f} ms round trip; server inference "
        f"{t.get('inference_ms', 0):.1f}, registration {t.get('registration_ms', 0):.1f} ms",
        "  wrote     " + "  ".join(str(p) for p in written),
    ]
    return "\n".join(lines)


def track_line(frame: str, answer: PoseAnswer) -> str:
    """One line per frame of ``sdc-client track``: the verdict, tracked or not, t, latency."""
    t = answer.pose.t
    reasons = f" ({', '.join(answer.reasons)})" if answer.reasons else ""
    if answer.answer["tracked"]:
        how = "tracked"
    else:
        how = "left its init" if "left_init" in answer.reasons else "from scratch"
    return (
        f"{frame}: {answer.verdict}{reasons}, {how}, "
        f"t [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] m, {answer.latency_s * 1e3:.0f} ms"
    )


def write_pose_outputs(
    out: Path, gray: np.ndarray, answer: PoseAnswer, points: np.ndarray
) -> list[Path]:
    """Write ``pose.json`` and ``preview.png`` into ``out`` (created); returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in POSE_OUTPUT_FILES]
    paths[0].write_text(json.dumps(answer.answer, indent=1) + "\n")
    cv2.imwrite(str(paths[1]), pose_preview(gray, answer, points))
    return paths


def read_init(text: str) -> dict:
    """``--init``: a pose as JSON text, or a file holding one (a previous ``pose.json``,
    whose ``pose`` is taken)."""
    path = Path(text)
    value = json.loads(path.read_text()) if path.is_file() else json.loads(text)
    return value.get("pose", value) if isinstance(value, dict) else value
