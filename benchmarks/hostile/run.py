"""Hostile and careless clients against the real service: every attack of issue 21 and more,
with the server's peak memory, ``/ready``'s latency meanwhile and a verdict for each.

    python -m benchmarks.hostile [--model PATH] [--only A,B1,...] [--name hostile] [--note TEXT]

Starts ``sdc-serve`` on 127.0.0.1 (a free port, 2 onnxruntime threads, every other setting its
default, a targets folder of one mesh for ``POST /pose``) on the tiny sdcnet-shaped model
(``tests.support.models.tiny_model``: it calls every bright pixel spacecraft, so a bright
frame is all foreground, the worst case for the point cloud) or ``--model``. After a warm-up
(valid frames on every route) the resident memory is the baseline. Then each attack runs in
turn: the server's peak resident memory is reset (``/proc/PID/clear_refs``) before it and read
(VmHWM) after it, and a thread polls ``GET /ready`` every 0.1 s meanwhile.

An attack passes when its own check holds (the status it must get, valid clients served, the
connection closed in time), its peak stays under 512 MiB above the baseline and ``/ready``
answered within 1 s throughout. The start-up attacks (I) run ``sdc-serve`` on broken targets
folders instead. Writes docs/benchmarks/NAME.md and NAME.json; exits 1 when an attack fails.
"""

from __future__ import annotations

import argparse
import json
import re
import tempfile
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from pathlib import Path

import httpx

from benchmarks.common import DOCS, cpu_description, write_markdown
from benchmarks.hostile.catalogue import ATTACKS
from benchmarks.hostile.client import (
    PEAK_LIMIT_MIB,
    READY_LIMIT_MS,
    V2,
    Context,
    Outcome,
    frame_files,
)
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
from tests.support.attacks import ReadyWatch, reset_peak
from tests.support.frames import png_bytes, synthetic_frame, v2_body
from tests.support.models import tiny_model
from tests.support.serving import memory_kib, service_process
from tests.support.targets import probe_mesh, write_targets

#: Resident memory an attack may leave above the warm baseline (the allocators keep what they
#: freed, for reuse) before the service is restarted, so that the next attack's peak is its own.
RETAINED_LIMIT_MIB = 64


@dataclass(frozen=True)
class Row:
    key: str
    attack: str
    expected: str
    answer: str
    seconds: float | None
    peak_mib: float | None
    ready_ms: float | None
    passed: bool


def warm_up(ctx: Context) -> None:
    """Valid frames on every route (the allocators keep what they grew), then the baseline."""
    s = synthetic_frame(1024, 2)
    files = {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
    for fmt in ("json", "npz", "ply"):
        for _ in range(3):
            assert ctx.post(f"/complete?format={fmt}", files=files)[0].status_code == 200
    content, headers = v2_body(s.gray, returns_from_dense(s.sparse))
    for _ in range(3):
        assert ctx.post(V2, content=content, headers=headers)[0].status_code == 200
        ctx.post("/pose", files=frame_files(), data={"target": "probe"})
    time.sleep(1.0)
    ctx.warm_kib = memory_kib(ctx.pid)["rss"]


def run_attack(ctx: Context, key: str) -> Row:
    what, expected, attack = ATTACKS[key]
    startup = key.startswith("I")
    reset_peak(ctx.pid)
    with ReadyWatch(ctx.url) as ready:
        try:
            outcome = attack(ctx)
        except Exception as exc:  # a transport error is an answer too
            outcome = Outcome(f"client error: {type(exc).__name__}: {exc}"[:200], None, False)
    peak_mib = (memory_kib(ctx.pid)["peak"] - ctx.warm_kib) / 1024
    ctx.peaks_mib[key] = peak_mib
    passed = outcome.ok and ready.max_ms <= READY_LIMIT_MS
    if not startup and key != "B5":
        passed = passed and peak_mib <= PEAK_LIMIT_MIB
    row = Row(
        key,
        what,
        expected,
        outcome.answer,
        outcome.seconds,
        None if startup else peak_mib,
        ready.max_ms,
        passed,
    )
    print(
        f"{key}: {'pass' if passed else 'FAIL'}: {outcome.answer} (peak +{peak_mib:.0f} MiB, "
        f"/ready max {ready.max_ms:.0f} ms)",
        flush=True,
    )
    return row


def internal_errors(url: str) -> float:
    """The service's count of requests that ended in an internal error."""
    text = httpx.get(f"{url}/metrics").text
    found = re.findall(
        r'^sdcnet_inference_request_failure_total\{reason="internal_error"\} (\S+)$', text, re.M
    )
    return float(found[0]) if found else 0.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(  # prog: run as a package, argv[0] is its __main__.py
        prog="python -m benchmarks.hostile",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: the tiny one)")
    p.add_argument("--only", default=None, help="comma-separated keys (default: every attack)")
    p.add_argument("--name", default="hostile", help="report name under docs/benchmarks/")
    p.add_argument("--note", default="", help="a sentence for the report (e.g. a shared machine)")
    args = p.parse_args(argv)
    keys = args.only.split(",") if args.only else list(ATTACKS)
    errors = 0.0
    with tempfile.TemporaryDirectory() as work:
        work_dir = Path(work)
        model = args.model or tiny_model(work_dir)
        targets = write_targets(work_dir / "targets", {"probe": (probe_mesh(), 6.3)})
        flags = ["--threads=2", f"--targets={targets}"]
        ctx = Context("", 0, model, work_dir, {})
        rows, restarts, warm = [], 0, []
        with ExitStack() as running:
            for key in keys:
                if not ctx.url:
                    service = running.enter_context(
                        service_process(model, work_dir / f"serve-{restarts}.log", *flags)
                    )
                    ctx.url, ctx.pid = service.url, service.pid
                    ctx.limits = httpx.get(f"{service.url}/model").json()["limits"]
                    warm_up(ctx)
                    warm.append(ctx.warm_kib / 1024)
                rows.append(run_attack(ctx, key))
                if memory_kib(ctx.pid)["rss"] > ctx.warm_kib + RETAINED_LIMIT_MIB * 1024:
                    errors += internal_errors(ctx.url)
                    running.close()  # a fresh service: the next attack's peak is its own
                    ctx.url, restarts = "", restarts + 1
            if ctx.url:
                errors += internal_errors(ctx.url)
        fives = sorted({s for s in ctx.statuses if s >= 500 and s != 503})
        limits = ctx.limits
    summary = {
        "model": "the tiny test model" if args.model is None else str(args.model),
        "machine": cpu_description(),
        "note": args.note,
        "limits": limits,
        "warm_rss_mib": warm,
        "restarts": restarts,
        "internal_errors": errors,
        "statuses_5xx": fives,
        "rows": [asdict(r) for r in rows],
    }
    (DOCS / f"{args.name}.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(write_report(args, summary, rows))
    failed = [r.key for r in rows if not r.passed]
    return 1 if failed or errors or fives else 0


def write_report(args: argparse.Namespace, summary: dict, rows: list[Row]) -> Path:
    def cell(value: float | None, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    table = "\n".join(
        f"| {r.key} | {r.attack} | {r.expected} | {r.answer} | {cell(r.peak_mib, '+.0f')} | "
        f"{cell(r.ready_ms, '.0f')} | {'pass' if r.passed else '**FAIL**'} |"
        for r in rows
    )
    command = "python -m benchmarks.hostile" + (f" --model {args.model}" if args.model else "")
    limits = ", ".join(f"{k} {v:,}" for k, v in summary["limits"].items())
    warm = " / ".join(f"{w:.0f}" for w in summary["warm_rss_mib"])
    passed = sum(r.passed for r in rows)
    body = f"""
`{command}` on {summary["machine"]}; model: {summary["model"]}. {summary["note"]}

`sdc-serve` with its default settings (limits: {limits}),
2 onnxruntime threads, on 127.0.0.1; warm baseline (resident memory after valid frames on
every route) {warm} MiB. "peak" is the server's peak resident memory (VmHWM, reset before each
attack) above that baseline; an attack that leaves more than {RETAINED_LIMIT_MIB} MiB resident
above it (the allocators keep freed memory for reuse) is followed by a fresh service
({summary["restarts"]} restarts), so that each peak is the attack's own. "/ready" is the slowest
of the probes sent every 0.1 s during the attack. An attack passes when its own check holds,
its peak stays under {PEAK_LIMIT_MIB:.0f} MiB (B5: under the Deployment's limit) and /ready
answered within {READY_LIMIT_MS:.0f} ms. The I rows start `sdc-serve` on a broken targets
folder instead.

**{passed} of {len(rows)} attacks pass**; requests counted as internal errors:
{summary["internal_errors"]:.0f}; 5xx answers other than 503: {summary["statuses_5xx"] or "none"}.

| | what the client sends | must | what happened | peak MiB | /ready ms | verdict |
|---|---|---|---|---|---|---|
{table}
"""
    return write_markdown(args.name, "Hostile and careless clients", body)
