"""Bytes on their way through the service, in memory up to ``SPOOL_MEMORY_BYTES`` and in a
temporary file beyond (``tempfile``'s directory: ``/tmp``, an ``emptyDir`` in the Kubernetes
Deployment).

A request's body is spooled while it arrives, before the request takes an in-flight place,
and an inference answer is spooled when it is encoded, before it leaves: a client that uploads
or downloads slowly holds a few megabytes of memory and some disk, never a frame's worth of
memory or a place another request could compute in (``sdcnet.service.admission``).
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator

from starlette.responses import Response
from starlette.types import Receive, Scope, Send

#: Bytes of a spool kept in memory; the rest goes to its temporary file. A 1024 x 1024 frame
#: sent by ``sdc-client`` (the raw image, the returns as a list) fits; a JSON answer of a
#: large frame does not, and is read back from the page cache.
SPOOL_MEMORY_BYTES = 2 * 2**20
#: Bytes read back at a time (one ASGI message).
CHUNK_BYTES = 2**20


class Spool:
    """Bytes written once (``write``, or any writer of binary files into ``file``), then read
    back in chunks from the start (``chunks``)."""

    def __init__(self, memory_bytes: int = SPOOL_MEMORY_BYTES):
        # closed by close(): a spool outlives the call that makes it
        self.file = tempfile.SpooledTemporaryFile(max_size=memory_bytes)  # noqa: SIM115

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.file.write(data)

    @property
    def size(self) -> int:
        """Bytes written (while writing)."""
        return self.file.tell()

    def chunks(self, size: int = CHUNK_BYTES) -> Iterator[bytes]:
        """The bytes from the start, ``size`` at a time."""
        self.file.seek(0)
        while chunk := self.file.read(size):
            yield chunk

    def close(self) -> None:
        self.file.close()


class SpooledResponse(Response):
    """An answer whose body is a ``Spool``, sent a chunk at a time with its Content-Length;
    the spool is closed once sent (or once the client is gone)."""

    def __init__(
        self,
        spool: Spool,
        media_type: str,
        headers: dict[str, str] | None = None,
        status_code: int = 200,
    ):
        self.spool = spool
        headers = {**(headers or {}), "content-length": str(spool.size)}
        super().__init__(None, status_code, headers, media_type)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await send(
                {
                    "type": "http.response.start",
                    "status": self.status_code,
                    "headers": self.raw_headers,
                }
            )
            for chunk in self.spool.chunks():
                await send({"type": "http.response.body", "body": chunk, "more_body": True})
            await send({"type": "http.response.body", "body": b"", "more_body": False})
        finally:
            self.spool.close()
