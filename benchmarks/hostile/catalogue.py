"""The catalogue of attacks: for each key, what the client sends, what must happen, and the
attack."""

from __future__ import annotations

from collections.abc import Callable

from benchmarks.hostile.client import Context, Outcome
from benchmarks.hostile.connections import (
    half_request_line,
    silent_connections,
    slow_readers,
    slowloris,
    trickling_uploads,
)
from benchmarks.hostile.inputs import (
    form_intrinsics,
    library_hints,
    pose_init,
    server_header,
    v2_deep_header,
    v2_intrinsics,
    v2_wide_shape,
)
from benchmarks.hostile.memory import (
    four_largest_frames,
    frame_4096,
    json_gray_of_largest_frame,
    largest_frame,
    largest_frame_json_outputs,
    largest_pose,
    largest_upload,
    long_csv,
    v2_json,
)
from benchmarks.hostile.overload import OVERLOAD_FRAMES, overload
from benchmarks.hostile.targets import broken_targets
from tests.support.attacks import huge_integer, nested_json

#: key -> (what the client sends, what must happen, the attack)
ATTACKS: dict[str, tuple[str, str, Callable[[Context], Outcome]]] = {
    "A": (
        "4 `POST /complete` uploads of a valid form (128 x 128 frame, 67 kB) sending one byte "
        "every 2 s, and 10 valid requests meanwhile",
        ">= 9 of 10 valid 200",
        trickling_uploads,
    ),
    "B1": (
        "v2 JSON: a [1, 1] gray with 15M zeros in `data` (30 MiB)",
        "4xx within 2 s",
        v2_json(15_000_000),
    ),
    "B2": ("v2 JSON: the same with 57M zeros (114 MiB)", "4xx within 2 s", v2_json(57_000_000)),
    "B3": (
        "a 4096 x 4096 bright frame, a return on every 4th pixel (1M), outlier removal, JSON",
        "no 5xx; 4xx, or 200 within 10 s",
        frame_4096,
    ),
    "B4": (
        "the largest frame the service takes (`max_pixels`), bright, 1 return in 16 pixels, "
        "outlier removal, JSON answer",
        "200",
        largest_frame,
    ),
    "B5": ("four B4 at once", "peak within the Deployment's memory limit", four_largest_frames),
    "B6": (
        "the largest bright frame (at most 2048 x 2048) over v2, every output asked as JSON `data`",
        "200 or 413",
        largest_frame_json_outputs,
    ),
    "B7": (
        "v2 JSON: the largest gray (at most 2048 x 2048) and its returns as JSON `data`",
        "200 or 413",
        json_gray_of_largest_frame,
    ),
    "B8": (
        "the largest frame as a 16-bit noise PNG and a float64 dense `.npy` (the largest files "
        "of a frame), outlier removal, JSON answer",
        "200, or 413 when the files exceed `max_upload_bytes`",
        largest_upload,
    ),
    "B9": (
        "the largest bright frame (1 return in 16 pixels) on `POST /pose`",
        "no 5xx",
        largest_pose,
    ),
    "C1": (
        "a returns CSV of 4M lines, the last one bad, beside the largest frame's gray",
        "4xx; within 2 s if more returns than the service takes, else 10 s",
        long_csv(4_000_000),
    ),
    "C2": ("the same with 16.7M lines", "as C1", long_csv(16_777_216)),
    "C3": (
        "the same with as many lines as the service takes (`max_returns`, at most a line per "
        "pixel)",
        "4xx within 10 s",
        long_csv(None),
    ),
    "D": (
        "`fx=1 fy=1` on a 1024 x 1024 frame",
        "422 invalid_intrinsics",
        form_intrinsics({"fx": "1", "fy": "1"}),
    ),
    "E1": (
        "`fx=1e-300` on `POST /complete`",
        "422 invalid_intrinsics",
        form_intrinsics({"fx": "1e-300"}),
    ),
    "E2": (
        "`cx=1e308` on `POST /complete`",
        "422 invalid_intrinsics",
        form_intrinsics({"cx": "1e308"}),
    ),
    "E3": ("`fx=1e-300` on the v2 route", "422 invalid_intrinsics", v2_intrinsics({"fx": 1e-300})),
    "E4": (
        "`cx=1e308` on `POST /pose`",
        "422 invalid_intrinsics",
        form_intrinsics({"cx": "1e308"}, "/pose"),
    ),
    "F1": ("half a request line, then silence", "closed within 30 s", half_request_line),
    "F2": (
        "50 connections sending their request head one line every 5 s (slowloris)",
        "all closed within 30 s; valid requests served",
        slowloris,
    ),
    "F3": ("200 connections that send nothing", "all closed within 30 s", silent_connections),
    "G1": (
        "32 clients sending 1024 x 1024 frames back to back for 20 s, ignoring Retry-After",
        f"200 or 503 only; answered p99 <= {OVERLOAD_FRAMES} frame times",
        overload(32),
    ),
    "G2": ("the same with 64 clients", "as G1", overload(64)),
    "H1": (
        "`POST /pose` with `init` nested 100,000 levels deep",
        "422 invalid_init within 2 s",
        pose_init(nested_json(100_000)),
    ),
    "H2": (
        "`POST /pose` with `init` nested 900 levels deep",
        "422 invalid_init within 2 s",
        pose_init(nested_json(900)),
    ),
    "H3": (
        "`POST /pose` with a 5000-digit number in `init`",
        "422 invalid_init within 2 s",
        pose_init(f'{{"t": [{huge_integer()}, 0, 0], "quaternion_wxyz": [1, 0, 0, 0]}}'),
    ),
    "I1": (
        'targets manifest with `"file": 5`',
        "exit 2, one line",
        broken_targets("file_not_text"),
    ),
    "I2": ('`"file": "../elsewhere.stl"`', "exit 2, one line", broken_targets("file_outside")),
    "I3": ("a symlink out of the folder", "exit 2, one line", broken_targets("symlink_outside")),
    "I4": ('`"longest_m": true`', "exit 2, one line", broken_targets("longest_true")),
    "I5": (
        '`"longest_m": 1e999` (infinite)',
        "exit 2, one line",
        broken_targets("longest_infinite"),
    ),
    "I6": ('`"longest_m": NaN`', "exit 2, one line", broken_targets("longest_nan")),
    "I7": (
        "a mesh whose triangles have no area",
        "exit 2, one line",
        broken_targets("degenerate_mesh"),
    ),
    "I8": (
        "a manifest that is an object, not a list",
        "exit 2, one line",
        broken_targets("manifest_not_a_list"),
    ),
    "J1": ("`GET /health`: the Server header", "none", server_header),
    "J2": (
        "errors that tempt library words (a 5000-digit .npy shape, a pickle, a 5000-digit "
        "number in `init` and in a v2 header), then every error message of this run",
        "no library hint or name",
        library_hints,
    ),
    "K1": (
        "4 clients asking for a 25 MB JSON answer and, once it has begun, reading none of it; "
        "10 valid requests meanwhile",
        ">= 9 of 10 valid 200; the readers reset (1 MiB/s after 10 s)",
        slow_readers,
    ),
    "K2": ("v2 header with `id` nested 100,000 levels deep", "4xx within 2 s", v2_deep_header),
    "K3": ("v2 header with a `shape` of 10M dimensions", "4xx within 2 s", v2_wide_shape),
}
