"""``sdc-client``: talk to an sdcnet service from the command line.

    sdc-client infer GRAY SPARSE [--out DIR] [--fx F --fy F --cx C --cy C] [--depth-scale S]
                                 [--max-sigma M] [--float16-depth]
        SPARSE: a .npy (metres), a 16-bit PNG (--depth-scale) or a row,col,z_m returns CSV
    sdc-client batch DIR_OR_MANIFEST --out DIR [--concurrency N] [--split test]
    sdc-client pose GRAY SPARSE --target NAME [--init POSE_JSON] [--out DIR] [intrinsics...]
    sdc-client track DIR_OR_MANIFEST --target NAME [--out DIR] [--split test]
        the frames in order, each from the motion so far (sdcnet.client.tracking)
    sdc-client health
    sdc-client model

Exit status: 0 done; 1 a batch with failed pairs; 2 a local input is missing or unreadable
(or the command line is wrong); 3 the service answered an error; 4 the service is unreachable
(or not ready, for ``health``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sdcnet.camera import PINHOLE_FIELDS, GivenIntrinsics
from sdcnet.cli import add_debug_flag, run_command
from sdcnet.client.api import (
    DEFAULT_URL,
    Client,
    ClientError,
    InputError,
    ServiceUnreachableError,
    gray_array,
    read_file,
)
from sdcnet.client.batch import find_pairs, run_batch
from sdcnet.client.outputs import gray_for_display, summary, write_outputs
from sdcnet.client.pose_outputs import pose_summary, read_init, track_line, write_pose_outputs
from sdcnet.client.tracking import Tracker

EXIT_OK, EXIT_FAILED_PAIRS, EXIT_INPUT, EXIT_SERVICE, EXIT_UNREACHABLE = 0, 1, 2, 3, 4


def _connection_options(defaults: bool) -> argparse.ArgumentParser:
    """``--url``, ``--timeout``, ``--retries`` and ``--debug``, taken before the command and
    after it (``sdc-client --url U infer ...`` as ``sdc-client infer --url U ...``): the
    top-level parser's copies hold the ``defaults``, the commands' copies none, so that an
    option given before the command is not overwritten by a command's default."""
    common = argparse.ArgumentParser(add_help=False)

    def default(value: object) -> object:
        return value if defaults else argparse.SUPPRESS

    common.add_argument(
        "--url",
        default=default(DEFAULT_URL),
        help=f"service URL (default: $SDCNET_URL or {DEFAULT_URL})",
    )
    common.add_argument("--timeout", type=float, default=default(60.0), help="seconds per attempt")
    common.add_argument(
        "--retries",
        type=int,
        default=default(3),
        help="retries on connection errors and 503",
    )
    add_debug_flag(common, default=default(False))
    return common


def _frame_options() -> argparse.ArgumentParser:
    frame = argparse.ArgumentParser(add_help=False)
    for name in PINHOLE_FIELDS:
        frame.add_argument(
            f"--{name}",
            type=float,
            help="intrinsics, pixels (default: the service's camera's, else the model's, scaled; "
            "a focal length alone keeps that camera's pixel aspect)",
        )
    frame.add_argument(
        "--depth-scale", type=float, help="metres per unit of a 16-bit PNG sparse map"
    )
    frame.add_argument(
        "--outlier-removal", action="store_true", help="statistical outlier removal on points"
    )
    frame.add_argument(
        "--max-sigma",
        type=float,
        help="metres: leave the points whose depth's 1-sigma uncertainty is above it out of "
        "the cloud",
    )
    return frame


def _depth_options() -> argparse.ArgumentParser:
    depth = argparse.ArgumentParser(add_help=False)
    depth.add_argument(
        "--float16-depth",
        action="store_true",
        help="depth as float16 on the wire: half the bytes, within 8 mm (default: exact)",
    )
    return depth


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sdc-client",
        description="Dense spacecraft depth from a gray image and sparse LIDAR depth, through "
        "an sdcnet service.",
        epilog="exit status: 0 ok, 1 some batch pairs failed, 2 bad local input, "
        "3 error answer from the service, 4 service unreachable or not ready",
        parents=[_connection_options(defaults=True)],
    )
    sub = p.add_subparsers(dest="command", required=True)
    common = _connection_options(defaults=False)
    frame, depth = _frame_options(), _depth_options()
    infer = sub.add_parser(
        "infer", parents=[common, frame, depth], help="complete one frame and write its files"
    )
    infer.add_argument("gray", type=Path, help="gray image: PNG, TIFF, JPEG or BMP")
    infer.add_argument(
        "sparse",
        type=Path,
        help=".npy (metres), 16-bit PNG (--depth-scale) or returns CSV (row,col,z_m per line)",
    )
    infer.add_argument("--out", type=Path, default=Path("sdcnet-out"), help="output folder")
    batch = sub.add_parser(
        "batch", parents=[common, frame, depth], help="complete many frames, a folder per frame"
    )
    batch.add_argument("source", type=Path, help="folder of pairs, JSON-lines manifest or dataset")
    batch.add_argument("--out", type=Path, required=True, help="output folder")
    batch.add_argument("--concurrency", type=int, default=2, help="requests at once")
    batch.add_argument("--split", help="dataset split to run (train, val, test...)")
    batch.add_argument("--no-progress", action="store_true", help="no progress bar")
    pose = sub.add_parser(
        "pose", parents=[common, frame], help="a known target's pose in one frame; preview"
    )
    pose.add_argument("gray", type=Path, help="gray image: PNG, TIFF, JPEG or BMP")
    pose.add_argument(
        "sparse",
        type=Path,
        help=".npy (metres), 16-bit PNG (--depth-scale) or returns CSV (row,col,z_m per line)",
    )
    pose.add_argument("--target", required=True, help="a known target's name (sdc-client model)")
    pose.add_argument(
        "--init", help="to track: a previous pose as JSON, or a pose.json this command wrote"
    )
    pose.add_argument("--out", type=Path, default=Path("sdcnet-pose"), help="output folder")
    track = sub.add_parser(
        "track",
        parents=[common, frame],
        help="a known target's pose over a sequence, each frame's init from the motion so far",
    )
    track.add_argument(
        "source",
        type=Path,
        help="the frames in time order: a folder of pairs (by name), a JSON-lines manifest or "
        "a dataset, as for batch",
    )
    track.add_argument("--target", required=True, help="a known target's name (sdc-client model)")
    track.add_argument("--split", help="dataset split to run (train, val, test...)")
    track.add_argument(
        "--out", type=Path, default=Path("sdcnet-track"), help="output folder: poses.jsonl"
    )
    sub.add_parser("health", parents=[common], help="is the service live and ready?")
    sub.add_parser("model", parents=[common], help="the service's model metadata (JSON)")
    return p


def frame_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The frame options of the command line, as ``Client.complete`` and ``Client.pose`` take
    them (and ``Pair.options`` as its defaults)."""
    return {
        "intrinsics": GivenIntrinsics.from_dict(vars(args)),
        "depth_scale": args.depth_scale,
        "max_sigma": args.max_sigma,
    }


def cmd_infer(client: Client, args: argparse.Namespace) -> int:
    gray = gray_array(args.gray)
    result = client.complete(
        gray,
        args.sparse,  # a file: the client reads it (a CSV's errors name it, line and return)
        outlier_removal=args.outlier_removal,
        float16_depth=args.float16_depth,
        **frame_kwargs(args),
    )
    written = write_outputs(args.out, gray, result)
    print(summary(result, client.url, written))
    return EXIT_OK


def cmd_batch(client: Client, args: argparse.Namespace) -> int:
    pairs = find_pairs(args.source, args.split)
    if not pairs:
        raise InputError(f"no pairs found in {args.source}")
    if not client.health()["ready"]:
        raise ServiceUnreachableError(f"the service at {client.url} is not ready")
    report = run_batch(
        client,
        pairs,
        args.out,
        concurrency=args.concurrency,
        outlier_removal=args.outlier_removal,
        float16_depth=args.float16_depth,
        defaults=frame_kwargs(args),
        progress=not args.no_progress,
    )
    print(report.summary())
    return EXIT_FAILED_PAIRS if report.failed else EXIT_OK


def cmd_pose(client: Client, args: argparse.Namespace) -> int:
    gray = read_file(args.gray, "gray image")
    try:
        init = read_init(args.init) if args.init else None
    except (OSError, ValueError) as exc:
        raise InputError(f"--init is neither pose JSON nor a readable pose.json: {exc}") from None
    answer = client.pose(
        gray,
        args.sparse,  # a file: the client reads it (a CSV's errors name it, line and return)
        args.target,
        init=init,
        outlier_removal=args.outlier_removal,
        **frame_kwargs(args),
    )
    points = client.target_points(args.target)
    written = write_pose_outputs(args.out, gray_for_display(gray_array(gray)), answer, points)
    print(pose_summary(answer, args.target, client.url, written))
    return EXIT_OK


def cmd_track(client: Client, args: argparse.Namespace) -> int:
    """Every frame of ``args.source`` in order through ``Tracker``: a line printed per frame,
    the answers in ``poses.jsonl`` (one JSON object a line, with its ``frame``)."""
    pairs = find_pairs(args.source, args.split)
    if not pairs:
        raise InputError(f"no pairs found in {args.source}")
    tracker = Tracker(client, args.target)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "poses.jsonl"
    with path.open("w") as poses:
        for pair in pairs:
            gray, sparse = pair.sources()
            options = pair.options(frame_kwargs(args))
            answer = tracker.pose(gray, sparse, outlier_removal=args.outlier_removal, **options)
            poses.write(json.dumps({"frame": pair.name, **answer.answer}) + "\n")
            print(track_line(pair.name, answer))
    print(f"wrote {path}")
    return EXIT_OK


def cmd_health(client: Client, args: argparse.Namespace) -> int:
    state = client.health()
    print(
        f"{client.url}: live {'yes' if state['live'] else 'no'}, "
        f"ready {'yes' if state['ready'] else 'no'}"
    )
    return EXIT_OK if state["ready"] else EXIT_UNREACHABLE


def cmd_model(client: Client, args: argparse.Namespace) -> int:
    print(json.dumps(client.model(), indent=2))
    return EXIT_OK


COMMANDS = {
    "infer": cmd_infer,
    "batch": cmd_batch,
    "pose": cmd_pose,
    "track": cmd_track,
    "health": cmd_health,
    "model": cmd_model,
}


#: Exit status of each kind of error (the first that matches); anything else is a bug.
USER_ERRORS = {
    InputError: EXIT_INPUT,
    ServiceUnreachableError: EXIT_UNREACHABLE,
    ClientError: EXIT_SERVICE,  # ServiceError, and answers the client cannot read
}


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)

    def command() -> int:
        with Client(args.url, timeout_s=args.timeout, retries=args.retries) as client:
            return COMMANDS[args.command](client, args)

    return run_command("sdc-client", command, USER_ERRORS, args.debug)


if __name__ == "__main__":
    sys.exit(main())
