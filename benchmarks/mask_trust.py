"""Whether an answer says when its mask is not to be trusted: the IOU each answer estimates
for its mask (``mask_iou_estimate``, ``sdcnet.caveats``) beside the IOU measured, and the poor
masks (IOU below ``POOR_IOU``) its caveats mark.

    python -m benchmarks.mask_trust --onnx models/sdcnet.onnx --sets data/any-s21:val \\
        data/robustness/* data/real data/paper:test --limit 288

Each set is a dataset directory, ``DIR:SPLIT`` for one split of it, at most ``--limit`` frames
each, evenly spread; every frame runs through ``sdcnet.pipeline.complete`` as the service runs
it. Writes docs/benchmarks/mask_trust.md and .json.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr
from tqdm import tqdm

from benchmarks.common import DOCS, set_records, write_markdown
from sdcnet.caveats import (
    CAVEATS,
    CROP_CUT_IOU_FACTOR,
    MASK_IOU_EXPONENT,
    UNCERTAIN_MASK_IOU,
    frame_caveats,
)
from sdcnet.evaluation.scoring import network
from sdcnet.metrics import frame_metrics
from sdcnet.pipeline import return_pixels
from sdcnet.runtime.onnx import OnnxModel

#: A mask below this IOU is a poor one, which an answer should say it may be.
POOR_IOU = 0.7
#: Edges of the estimate's bins in the calibration table.
BINS = (0.0, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 1.0)


def frame_rows(model: OnnxModel, spec: str, limit: int | None) -> list[dict]:
    """Per frame: the IOU measured, the answer's estimate and its caveats."""
    method = network(model.run, model.stride, model.info.work_pixels)
    store, records = set_records(spec, limit)
    rows = []
    for record in tqdm(records, desc=spec, unit="frame", leave=False):
        sample = store.load(record)
        answer = method(sample)
        returns = len(return_pixels(sample.sparse)[0])
        rows.append(
            {
                "id": sample.meta["id"],
                "iou": frame_metrics(answer.depth, answer.mask, sample.depth)["IOU"],
                "estimate": answer.completion.mask_iou_estimate,
                "caveats": frame_caveats(answer.completion, returns),
            }
        )
    return rows


def set_summary(rows: list[dict]) -> dict:
    """One set's row of the table."""
    iou = np.array([r["iou"] for r in rows])
    estimate = np.array([r["estimate"] for r in rows])
    poor = iou < POOR_IOU
    before = np.array([marked_before_crop_cut(r) for r in rows], dtype=bool)
    flagged = np.array([bool(r["caveats"]) for r in rows], dtype=bool)
    return {
        "frames": len(rows),
        "iou": float(iou.mean()),
        "estimate": float(estimate.mean()),
        "abs_error": float(np.abs(estimate - iou).mean()),
        "rank_correlation": float(spearmanr(estimate, iou).statistic),
        "poor": int(poor.sum()),
        "poor_marked_before": int((poor & before).sum()),
        "poor_marked": int((poor & flagged).sum()),
        "marked": int(flagged.sum()),
        "iou_marked": float(iou[flagged].mean()) if flagged.any() else float("nan"),
        "iou_unmarked": float(iou[~flagged].mean()) if (~flagged).any() else float("nan"),
    }


def marked_before_crop_cut(row: dict) -> bool:
    """Whether a frame carried a caveat before ``crop_cut`` came (with its factor of the
    estimate): ``few_returns``, ``lidar_field_cut``, or the estimate without the factor below
    ``UNCERTAIN_MASK_IOU``."""
    estimate = row["estimate"]
    if "crop_cut" in row["caveats"]:
        estimate /= CROP_CUT_IOU_FACTOR
    codes = set(row["caveats"]) & {"few_returns", "lidar_field_cut"}
    return bool(codes) or estimate < UNCERTAIN_MASK_IOU


def calibration(rows: list[dict]) -> list[dict]:
    """The frames binned by their estimate: mean estimate and mean IOU measured per bin."""
    iou = np.array([r["iou"] for r in rows])
    estimate = np.array([r["estimate"] for r in rows])
    out = []
    for lo, hi in itertools.pairwise(BINS):
        inside = (estimate >= lo) & ((estimate < hi) | (hi == BINS[-1]))
        if inside.any():
            out.append(
                {
                    "bin": f"{lo:.2f}-{hi:.2f}",
                    "frames": int(inside.sum()),
                    "estimate": float(estimate[inside].mean()),
                    "iou": float(iou[inside].mean()),
                }
            )
    return out


def per_caveat(rows: list[dict]) -> list[dict]:
    """Per caveat code: the frames it marks, their mean IOU and the others', and the poor
    masks it marks, and marks alone."""
    iou = np.array([r["iou"] for r in rows])
    poor = iou < POOR_IOU
    out = []
    for code in CAVEATS:
        marked = np.array([code in r["caveats"] for r in rows], dtype=bool)
        alone = np.array([r["caveats"] == [code] for r in rows], dtype=bool)
        out.append(
            {
                "code": code,
                "marked": int(marked.sum()),
                "iou_marked": float(iou[marked].mean()) if marked.any() else float("nan"),
                "iou_unmarked": float(iou[~marked].mean()) if (~marked).any() else float("nan"),
                "poor_marked": int((poor & marked).sum()),
                "poor_marked_alone": int((poor & alone).sum()),
            }
        )
    return out


def fitted_exponent(rows: list[dict]) -> float:
    """The exponent of ``expected_iou`` that fits the IOU measured on ``rows`` best (least
    squares, to 0.01): how ``MASK_IOU_EXPONENT`` was chosen, on the validation frames. The
    frames that carry ``crop_cut`` count with their estimate's factor taken out."""
    estimate = np.array([r["estimate"] for r in rows])
    cut = np.array(["crop_cut" in r["caveats"] for r in rows], dtype=bool)
    raw = np.where(cut, estimate / CROP_CUT_IOU_FACTOR, estimate) ** (1 / MASK_IOU_EXPONENT)
    iou = np.array([r["iou"] for r in rows])
    exponents = np.arange(0.5, 4.0, 0.01)
    errors = [np.sum((raw**e - iou) ** 2) for e in exponents]
    return float(exponents[int(np.argmin(errors))])


def fitted_crop_cut_factor(rows: list[dict]) -> tuple[float, int]:
    """The factor of the estimate that fits the IOU measured best (least squares) on those of
    ``rows`` that carry ``crop_cut``, and how many they are: how ``CROP_CUT_IOU_FACTOR`` was
    chosen, on the validation frames."""
    cut = [r for r in rows if "crop_cut" in r["caveats"]]
    if not cut:
        return float("nan"), 0
    raw = np.array([r["estimate"] for r in cut]) / CROP_CUT_IOU_FACTOR
    iou = np.array([r["iou"] for r in cut])
    return float(np.dot(raw, iou) / np.dot(raw, raw)), len(cut)


def pct(value: float) -> str:
    return f"{100 * value:.1f}"


def sets_table(summaries: dict[str, dict]) -> str:
    lines = [
        "| set | frames | IOU % | estimated % | mean abs. difference, points | rank correlation | "
        f"IOU < {pct(POOR_IOU)} % | of which marked, before / now | frames marked | "
        "IOU marked / not % |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summaries.items():
        lines.append(
            f"| {name} | {s['frames']} | {pct(s['iou'])} | {pct(s['estimate'])} | "
            f"{pct(s['abs_error'])} | {s['rank_correlation']:.2f} | {s['poor']} | "
            f"{s['poor_marked_before']} / {s['poor_marked']} | {s['marked']} | "
            f"{pct(s['iou_marked'])} / {pct(s['iou_unmarked'])} |"
        )
    return "\n".join(lines)


def caveats_table(codes: list[dict]) -> str:
    lines = [
        f"| caveat | frames marked | IOU marked / not % | IOU < {pct(POOR_IOU)} % marked | "
        "of which by it alone |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| `{c['code']}` | {c['marked']} | {pct(c['iou_marked'])} / {pct(c['iou_unmarked'])} | "
        f"{c['poor_marked']} | {c['poor_marked_alone']} |"
        for c in codes
    ]
    return "\n".join(lines)


def calibration_table(bins: list[dict]) -> str:
    lines = ["| estimate | frames | mean estimate % | mean IOU % |", "|---|---|---|---|"]
    lines += [
        f"| {b['bin']} | {b['frames']} | {pct(b['estimate'])} | {pct(b['iou'])} |" for b in bins
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--onnx", type=Path, default=Path("models/sdcnet.onnx"))
    p.add_argument("--sets", nargs="+", required=True, help="DIR or DIR:SPLIT, each a set")
    p.add_argument("--limit", type=int, default=None, help="frames per set, evenly spread")
    p.add_argument(
        "--fitted-on",
        default="data/any-s21:val",
        help="the set MASK_IOU_EXPONENT was fitted on: left out of the pooled calibration",
    )
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    model = OnnxModel(args.onnx, threads=args.threads)
    rows = {spec: frame_rows(model, spec, args.limit) for spec in args.sets}
    summaries = {spec: set_summary(r) for spec, r in rows.items()}
    unseen = [row for spec, r in rows.items() if spec != args.fitted_on for row in r]
    bins = calibration(unseen)
    codes = per_caveat(unseen)
    poor_unseen = sum(row["iou"] < POOR_IOU for row in unseen)
    if args.fitted_on in rows:
        factor, cut = fitted_crop_cut_factor(rows[args.fitted_on])
        fitted = (
            f"Fitted on its {len(rows[args.fitted_on])} frames again, the least-squares exponent "
            f"is {fitted_exponent(rows[args.fitted_on]):.2f}, and the factor on its {cut} frames "
            f"that carry `crop_cut` {factor:.2f}."
        )
    else:
        fitted = f"(`{args.fitted_on}` not among the sets: the exponent not fitted again.)"
    command = f"python -m benchmarks.mask_trust --onnx {args.onnx} --sets {' '.join(args.sets)}"
    command += f" --limit {args.limit}" if args.limit else ""
    body = f"""
Each answer carries `mask_iou_estimate`, the IOU its mask is likely to score, from the
network's own foreground probability p on the working grid: (sum of p on the mask / (mask
pixels + sum of p off it)) ** {MASK_IOU_EXPONENT}, times {CROP_CUT_IOU_FACTOR} where the mask
reached its crop's side (`crop_cut`), both fitted on `{args.fitted_on}`; below
{UNCERTAIN_MASK_IOU} it carries the caveat `mask_uncertain`. {fitted}
Per set, the estimate beside the IOU measured (means over frames), and the poor masks (IOU
below {pct(POOR_IOU)} %) that a caveat marks: before `crop_cut`, by `few_returns`,
`lidar_field_cut` or the estimate without its factor below {UNCERTAIN_MASK_IOU}; now, by any of
the {len(CAVEATS)}.
Model `{args.onnx}`. Regenerate: `{command}`

{sets_table(summaries)}

Every set but `{args.fitted_on}`, the frames binned by their estimate:

{calibration_table(bins)}

Every set but `{args.fitted_on}`, per caveat ({len(unseen)} frames, {poor_unseen} of them
below {pct(POOR_IOU)} %):

{caveats_table(codes)}
"""
    print(write_markdown("mask_trust", "Whether an answer says when its mask is poor", body))
    (DOCS / "mask_trust.json").write_text(
        json.dumps(
            {"sets": summaries, "calibration": bins, "caveats": codes, "frames": rows}, indent=1
        )
        + "\n"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
