"""The pose evaluation's report (``sdc-eval pose``): per evaluation, the tables per cloud,
per trajectory and per spacecraft, in markdown and JSON, and reading the JSON back."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import asdict
from pathlib import Path

import numpy as np

from sdcnet.evaluation.pose_eval import SUCCESS_DEG, SUCCESS_M, FrameResult

VERDICTS = ("reliable", "ambiguous", "unreliable")


def summary(results: list[FrameResult]) -> dict[str, float]:
    """Means over frames; a frame without a pose counts as a failure, not in the errors."""
    posed = [r for r in results if np.isfinite(r.rotation_deg)]
    rot = np.array([r.rotation_deg for r in posed])
    trans = np.array([r.translation_m for r in posed])
    share = np.array([100 * r.translation_m / r.range_m for r in posed])
    verdicts = {v: 100 * float(np.mean([r.verdict == v for r in results])) for v in VERDICTS}
    return {
        "frames": len(results),
        "no_pose": len(results) - len(posed),
        "rotation_mean_deg": float(rot.mean()) if len(rot) else float("nan"),
        "rotation_median_deg": float(np.median(rot)) if len(rot) else float("nan"),
        "translation_mean_m": float(trans.mean()) if len(trans) else float("nan"),
        "translation_median_m": float(np.median(trans)) if len(trans) else float("nan"),
        "translation_mean_pct_range": float(share.mean()) if len(share) else float("nan"),
        "success_pct": 100 * float(np.mean([r.success for r in results])),
        "symmetric_success_pct": 100 * float(np.mean([r.symmetric_success for r in results])),
        **{f"verdict_{v}_pct": share for v, share in verdicts.items()},
        "reliable_but_wrong": sum(r.reliable_but_wrong for r in results),
        "among_answers_pct": 100 * float(np.mean([r.among_answers for r in results])),
        "ambiguous_pct": 100 * float(np.mean([r.ambiguous for r in results])),
        **{
            f"registration_{name}_ms": float(np.percentile([r.registration_ms for r in results], q))
            for name, q in (("p50", 50), ("p95", 95), ("max", 100))
        },
        "cloud_p50_ms": float(np.median([r.cloud_ms for r in results])),
    }


def table(rows: dict[str, dict[str, float]]) -> str:
    """Markdown: one row per (what, cloud)."""
    lines = [
        "| | frames | rot. mean deg | rot. median | transl. mean m | median | % of range | "
        "success (2 deg, 0.2 m) | modulo symmetry | truth among answers | ambiguous | "
        "verdict reliable / ambiguous / unreliable | reliable but wrong | "
        "registration p50 / p95 / max ms | cloud p50 ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in rows.items():
        lines.append(
            f"| {name} | {s['frames']} | {s['rotation_mean_deg']:.2f} | "
            f"{s['rotation_median_deg']:.2f} | {s['translation_mean_m']:.3f} | "
            f"{s['translation_median_m']:.3f} | {s['translation_mean_pct_range']:.3f} | "
            f"{s['success_pct']:.1f} % | {s['symmetric_success_pct']:.1f} % | "
            f"{s['among_answers_pct']:.1f} % | {s['ambiguous_pct']:.1f} % | "
            f"{s['verdict_reliable_pct']:.0f} / {s['verdict_ambiguous_pct']:.0f} / "
            f"{s['verdict_unreliable_pct']:.0f} % | "
            f"{s['reliable_but_wrong']} | {s['registration_p50_ms']:.1f} / "
            f"{s['registration_p95_ms']:.1f} / {s['registration_max_ms']:.1f} | "
            f"{s['cloud_p50_ms']:.1f} |"
        )
    return "\n".join(lines)


def grouped(results: list[FrameResult], key) -> dict[str, list[FrameResult]]:
    groups: dict[str, list[FrameResult]] = defaultdict(list)
    for r in results:
        groups[key(r)].append(r)
    return dict(sorted(groups.items()))


def report(results: dict[str, list[FrameResult]], clouds_order: list[str]) -> tuple[str, dict]:
    """Markdown and JSON of every evaluation (name -> frame results): per cloud (and mode:
    a sequence's first frame is found from scratch), per trajectory, per spacecraft."""

    def key(r: FrameResult) -> str:
        return r.cloud if r.mode == "scratch" and not r.trajectory else f"{r.cloud}, {r.mode}"

    def order(k: str) -> tuple:
        cloud = k.split(",")[0]
        return (clouds_order.index(cloud) if cloud in clouds_order else 99, k)

    lines, data = [], {}
    for name, frames in results.items():
        rows = grouped(frames, key)
        overall = {k: summary(rows[k]) for k in sorted(rows, key=order)}
        data[name] = {"overall": overall}
        lines += [f"### {name}", "", table(overall), ""]
        tracked = [r for r in frames if r.mode == "tracking"]
        if tracked:
            per_trajectory = {
                f"{trajectory}, {cloud}": summary(rs)
                for trajectory, runs in grouped(tracked, lambda r: r.trajectory).items()
                for cloud, rs in sorted(
                    grouped(runs, lambda r: r.cloud).items(), key=lambda i: order(i[0])
                )
            }
            data[name]["per_trajectory"] = per_trajectory
            lines += [f"#### {name}: tracking per trajectory", "", table(per_trajectory), ""]
        per_craft = {
            f"{craft}, {k}": summary(rs)
            for craft, craft_frames in grouped(frames, lambda r: r.spacecraft).items()
            for k, rs in sorted(grouped(craft_frames, key).items(), key=lambda i: order(i[0]))
        }
        data[name]["per_spacecraft"] = per_craft
        data[name]["frames"] = [asdict(r) for r in frames]
        lines += [f"#### {name}: per spacecraft", "", table(per_craft), ""]
    every = [r for frames in results.values() for r in frames]
    reliable = [r for r in every if r.verdict == "reliable"]
    wrong = sum(r.reliable_but_wrong for r in reliable)
    lines.append(
        f"Over all {len(every)} answers: {len(reliable)} marked reliable, of which {wrong} "
        f"wrong (beyond {SUCCESS_DEG:g} degrees or {SUCCESS_M:g} m)."
    )
    if reliable:
        rotation, translation = sigma_coverage(reliable)
        lines += [
            "",
            "Of those marked reliable, the errors within 1 / 2 / 3 times the answer's own "
            "sigma: rotation "
            + " / ".join(f"{c:.0f}" for c in rotation)
            + " %, translation "
            + " / ".join(f"{c:.0f}" for c in translation)
            + " % (an isotropic Gaussian error with that sigma per axis: "
            + " / ".join(f"{c:.0f}" for c in GAUSSIAN_COVERAGE)
            + " %).",
        ]
    return "\n".join(lines), data


#: Per cent of the errors within 1, 2 and 3 sigma for an isotropic 3-D Gaussian error of
#: standard deviation sigma per axis (the error's norm follows a chi distribution, 3 degrees).
GAUSSIAN_COVERAGE = (19.9, 73.9, 97.1)


def sigma_coverage(results: list[FrameResult]) -> tuple[list[float], list[float]]:
    """Per cent of ``results`` whose rotation (then translation) error is within 1, 2 and 3
    times the answer's ``rotation_sigma_deg`` (``translation_sigma_m``); an answer without a
    sigma counts as not covered."""

    def within(errors: np.ndarray, sigmas: np.ndarray) -> list[float]:
        return [100 * float(np.mean(errors <= k * sigmas)) for k in (1, 2, 3)]

    rows = np.array(
        [
            (r.rotation_deg, r.rotation_sigma_deg, r.translation_m, r.translation_sigma_m)
            for r in results
        ]
    ).reshape(-1, 4)
    return within(rows[:, 0], rows[:, 1]), within(rows[:, 2], rows[:, 3])


def read_report(path: Path) -> dict[str, list[FrameResult]]:
    """The frame results of a ``report`` JSON, by evaluation name."""
    data = json.loads(Path(path).read_text())
    return {name: [FrameResult(**f) for f in v["frames"]] for name, v in data.items()}
