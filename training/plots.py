"""Learning-curve plot of a training run (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def learning_curves(history: list[dict], path: Path) -> None:
    """Train loss, val IOU and val MATE / MAEI per epoch, one colour per stage; epochs are
    counted through both stages."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    stage1_epochs = sum(1 for r in history if r["stage"] == 1)
    for stage, colour in ((1, "tab:blue"), (2, "tab:orange")):
        rows = [r for r in history if r["stage"] == stage]
        if not rows:
            continue
        x = [r["epoch"] + (stage1_epochs if stage == 2 else 0) for r in rows]
        label = "stage 1 (FSNet, BCE)" if stage == 1 else "stage 2 (FDCNet, L1)"
        axes[0].plot(x, [r["train_loss"] for r in rows], "o-", color=colour, label=label)
        axes[1].plot(x, [100 * r["IOU"] for r in rows], "o-", color=colour, label=label)
        axes[2].plot(x, [r["MATE"] for r in rows], "o-", color=colour, label=f"MATE, {label}")
        axes[2].plot(x, [r["MAEI"] for r in rows], "s--", color=colour, label=f"MAEI, {label}")
    for ax, title in zip(axes, ("train loss", "val IOU %", "val error (m)"), strict=True):
        ax.set_title(title)
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
