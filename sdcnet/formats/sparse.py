"""The files that carry a frame's LIDAR returns, one ``InputFormat`` each, told apart by their
first bytes: the service (``sdcnet.service.decode``) and the client (``sdcnet.client.api``)
read them, and the texts that list them (form fields, 415 answers, batch folders) are made
from ``FORMATS``. A new format is a module of ``sdcnet.formats`` and a line here."""

from __future__ import annotations

from sdcnet.formats import InputFormat, csv_returns, npy, png16

#: In the order they are tried; CSV, which takes any bytes as text, last.
FORMATS: tuple[InputFormat, ...] = (npy.FORMAT, png16.FORMAT, csv_returns.FORMAT)
#: Every format's file endings, in that order.
ENDINGS = tuple(ending for format_ in FORMATS for ending in format_.endings)


def sparse_format(data: bytes) -> InputFormat:
    """The first format that recognises ``data``'s first bytes."""
    return next(format_ for format_ in FORMATS if format_.recognise(data))


def described(carried: str) -> str:
    """The formats that carry a ``"map"`` or a ``"list"``, in words: "a .npy of ... or a CSV
    ..."."""
    lines = [format_.carries[carried] for format_ in FORMATS if carried in format_.carries]
    return " or ".join([", ".join(lines[:-1]), lines[-1]] if len(lines) > 1 else lines)
