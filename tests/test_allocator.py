"""The allocator settings the service applies: each one, unless glibc's variable is set."""

import ctypes
import subprocess
import sys

import pytest

from sdcnet import allocator


class FakeLibc:
    def __init__(self):
        self.calls: list[tuple[int, int]] = []

    def mallopt(self, parameter: int, value: int) -> int:
        self.calls.append((parameter, value))
        return 1


@pytest.fixture
def libc(monkeypatch):
    fake = FakeLibc()
    monkeypatch.setattr(ctypes, "CDLL", lambda name: fake)
    for variable in ("MALLOC_ARENA_MAX", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"):
        monkeypatch.delenv(variable, raising=False)
    return fake


M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8  # glibc's malloc.h


def test_the_arenas_are_capped_and_freed_frames_kept_for_the_next(libc):
    allocator.configure_malloc()
    assert libc.calls == [
        (M_ARENA_MAX, 1),
        (M_MMAP_THRESHOLD, 32 * 2**20),  # a 2048 x 2048 float32 map (16 MiB) is below it
        (M_TRIM_THRESHOLD, 2**30),
    ]


def test_glibcs_own_variables_win(libc, monkeypatch):
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "131072")
    allocator.configure_malloc()
    assert [parameter for parameter, _ in libc.calls] == [M_ARENA_MAX, M_TRIM_THRESHOLD]


def test_another_c_library_is_left_alone(monkeypatch):
    def missing(name):
        raise OSError(f"{name}: cannot open shared object file")

    monkeypatch.setattr(ctypes, "CDLL", missing)
    allocator.configure_malloc()  # no error


def test_sdc_serve_sets_the_allocator_up_before_any_library_starts_a_thread():
    """numpy, OpenCV and onnxruntime each start a thread when imported, and a thread that
    allocates gets an arena before a cap set later can stop it: ``sdc-serve``'s entry point
    imports none of them, and the process has one thread, until ``configure_malloc`` ran."""
    code = (
        "import re, sys, sdcnet.service.launch\n"
        "print(sorted(m for m in ('numpy', 'cv2', 'onnxruntime') if m in sys.modules))\n"
        "print(re.search(r'Threads:\\s+(\\d+)', open('/proc/self/status').read()).group(1))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[:2] == ["[]", "1"]
