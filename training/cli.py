"""``sdc-train``: fit SDCNet (or an ablation variant), copy a checkpoint to ship, average
checkpoints, calibrate its sigma. Evaluation is ``sdc-eval``'s."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import MISSING, Field, fields
from pathlib import Path
from typing import get_args, get_type_hints

from sdcnet.cli import FILE_AND_VALUE_ERRORS, add_debug_flag, run_command
from sdcnet.training.checkpoint import average_checkpoints, ship_checkpoint
from sdcnet.training.train import PRESETS, TrainConfig, Trainer, config_from_preset

#: What a user's mistake raises (a missing or bad file, a bad value): one line, exit 2.


def flag_fields() -> list[Field]:
    """The fields of ``TrainConfig`` that are flags of ``sdc-train fit``."""
    return [f for f in fields(TrainConfig) if f.metadata.get("flag", True)]


def add_config_flags(parser: argparse.ArgumentParser) -> None:
    """One flag per field of ``TrainConfig`` (``--batch-size`` for ``batch_size``): its type
    (``int | None`` gives int), its help and choices from the field's metadata, required when
    the field has no default. A flag not given is None, so that the preset and ``--config``
    fill it."""
    hints = get_type_hints(TrainConfig)
    for f in flag_fields():
        kind = next(k for k in (*get_args(hints[f.name]), hints[f.name]) if k is not type(None))
        # a switch is --name / --no-name (argparse's bool("False") would be True)
        how = {"action": argparse.BooleanOptionalAction} if kind is bool else {"type": kind}
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            dest=f.name,
            **how,
            required=f.default is MISSING and f.default_factory is MISSING,
            **{k: v for k, v in f.metadata.items() if k in ("help", "choices")},
        )


def cmd_fit(args: argparse.Namespace) -> int:
    """Train with the preset, then the ``--config`` file, then the flags given, each
    overriding the one before."""
    overrides = json.loads(Path(args.config).read_text()) if args.config else {}
    for f in flag_fields():
        value = getattr(args, f.name)
        if value is not None:
            overrides[f.name] = value
    config = config_from_preset(args.preset, **overrides)
    best = Trainer(config).fit(resume=not args.restart)
    print(f"best checkpoint: {best}")
    return 0


def cmd_ship(args: argparse.Namespace) -> int:
    ship_checkpoint(args.checkpoint, args.out, args.zero)
    print(f"wrote {args.out} ({Path(args.out).stat().st_size / 1e6:.2f} MB)")
    return 0


def cmd_average(args: argparse.Namespace) -> int:
    average_checkpoints(args.checkpoints, args.out)
    print(f"wrote {args.out}: the mean of {len(args.checkpoints)} checkpoints' weights")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from sdcnet.training.uncertainty import calibrate_checkpoint

    print(
        calibrate_checkpoint(
            args.checkpoint, args.data, args.out, args.split, args.limit, args.edge_weight
        )
    )
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-train", description=__doc__)
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="two-stage training; resumes from OUT/last.pt")
    f.add_argument("--preset", default="cpu", choices=sorted(PRESETS), help="recipe (default: cpu)")
    f.add_argument("--config", help="JSON file of TrainConfig fields (flags override it)")
    add_config_flags(f)
    f.add_argument("--restart", action="store_true", help="ignore OUT/last.pt")
    f.set_defaults(func=cmd_fit)

    s = sub.add_parser("ship", help="copy a checkpoint without the optimiser state (to commit)")
    s.add_argument("--checkpoint", required=True)
    s.add_argument("--out", required=True)
    s.add_argument(
        "--zero",
        nargs="*",
        default=[],
        metavar="PREFIX",
        help="ablation copies: set the weights under these prefixes to 0, e.g. fdcnet.head "
        "(depth = the plane fit alone) or refiner.correction (FSNet without its refiner)",
    )
    s.set_defaults(func=cmd_ship)

    a = sub.add_parser(
        "average",
        help="the mean of checkpoints' weights (fine-tuned from one model: a model soup)",
    )
    a.add_argument("--checkpoints", nargs="+", required=True, metavar="CHECKPOINT")
    a.add_argument("--out", required=True)
    a.set_defaults(func=cmd_average)

    k = sub.add_parser(
        "calibrate", help="scale the depth's sigma to cover 68 %% of the errors on a split"
    )
    k.add_argument("--checkpoint", required=True)
    k.add_argument("--data", required=True, help="a dataset whose split was not trained on")
    k.add_argument("--split", default="val")
    k.add_argument("--limit", type=int, default=90, help="frames, evenly spread")
    k.add_argument(
        "--edge-weight",
        type=float,
        default=0.5,
        help="sigma's depth-edge term per metre of local depth spread, before the scaling "
        "(0: the scale head alone)",
    )
    k.add_argument("--out", required=True, help="the calibrated checkpoint")
    k.set_defaults(func=cmd_calibrate)

    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-train", lambda: args.func(args), FILE_AND_VALUE_ERRORS, args.debug)


if __name__ == "__main__":
    sys.exit(main())
