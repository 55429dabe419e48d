"""``sdc-serve``'s entry point (and ``python -m sdcnet.service``'s): glibc's malloc settings
(``sdcnet.allocator``) first, then the service.

numpy, OpenCV and onnxruntime each start a thread when imported, and a thread that allocates
gets a malloc arena of its own: a cap on the arenas set after those imports caps nothing, and
the service's request threads then took turns on arenas the start-up's warm-up never wrote,
its first large frames faulting their memory in (``benchmarks.first_frames``:
docs/development.md, "Measurements"). So nothing but the allocator's settings may be imported
before them.
"""

from sdcnet.allocator import configure_malloc


def main(argv: list[str] | None = None) -> int:
    configure_malloc()
    from sdcnet.service.cli import main as serve  # numpy, OpenCV, onnxruntime: threads

    return serve(argv)
