"""sdcnet.formats: the parsers the service and the client share, and how each side answers
their errors (the service's status per code, the client's InputError)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sdcnet.client.api import InputError, returns_list
from sdcnet.formats import FormatError, npy
from sdcnet.formats.image_header import HeaderError, UnknownFormatError, read_header
from sdcnet.formats.png16 import depth_from_png16
from sdcnet.formats.sparse import sparse_format
from sdcnet.npyio import npy_bytes
from sdcnet.returns import write_returns_csv
from sdcnet.service.errors import format_error


def test_the_first_bytes_tell_the_sparse_formats_apart():
    png = b"\x89PNG\r\n\x1a\n" + bytes(20)
    assert sparse_format(npy_bytes(np.zeros((2, 2), np.float32))).name == ".npy"
    assert sparse_format(png).name == "16-bit PNG"
    assert sparse_format(b"row,col,z_m\n1,2,3\n").name == "CSV"


def test_npy_floats_are_read_as_float32_in_either_order():
    values = np.arange(6, dtype=np.float64).reshape(2, 3)
    read = npy.read_floats(npy_bytes(np.asfortranarray(values)), "sparse")
    assert read.dtype == np.float32 and read.flags.c_contiguous
    np.testing.assert_array_equal(read, values)


def test_the_shape_is_checked_before_the_data_is_read():
    header_only = npy_bytes(np.zeros((1000, 1000), np.float32))[:128]
    seen = []

    def refuse(shape):
        seen.append(shape)
        raise FormatError("too large", "wrong_shape")

    with pytest.raises(FormatError, match="too large"):
        npy.read_floats(header_only, "sparse", refuse)
    assert seen == [(1000, 1000)]


@pytest.mark.parametrize(
    ("data", "code"),
    [
        (npy_bytes(np.array([{}], object), allow_pickle=True), "pickle_not_allowed"),
        (npy_bytes(np.zeros((2, 2), np.int32)), "wrong_dtype"),
        (npy_bytes(np.zeros((4, 4), np.float32))[:-8], "unreadable_file"),
        (b"\x93NUMPY\x01\x00\x04\x00{}\n\n", "unreadable_file"),
    ],
    ids=["pickled", "integers", "truncated", "not_a_header"],
)
def test_npy_errors_carry_their_code(data, code):
    with pytest.raises(FormatError) as caught:
        npy.read_floats(data, "returns")
    assert caught.value.code == code
    assert str(caught.value).startswith("returns")


def test_a_16_bit_png_is_units_times_the_scale_and_nothing_else():
    units = np.array([[0, 1000], [2500, 65535]], np.uint16)
    np.testing.assert_array_equal(
        depth_from_png16(units, 0.001), units.astype(np.float32) * np.float32(0.001)
    )
    for image in (units.astype(np.uint8), np.zeros((2, 2, 3), np.uint16)):
        with pytest.raises(FormatError) as caught:
            depth_from_png16(image, 0.001)
        assert caught.value.code == "wrong_dtype"


def test_image_header_errors_are_format_errors_with_their_codes():
    with pytest.raises(UnknownFormatError) as unknown:
        read_header(b"GIF89a" + bytes(20))
    with pytest.raises(HeaderError) as broken:
        read_header(b"\x89PNG\r\n\x1a\n" + bytes(4))
    assert (unknown.value.code, broken.value.code) == ("unsupported_media_type", "unreadable_file")


@pytest.mark.parametrize(
    ("code", "status"),
    [
        ("unsupported_media_type", 415),
        ("unreadable_file", 400),
        ("pickle_not_allowed", 400),
        ("wrong_dtype", 422),
        ("wrong_shape", 422),
        ("invalid_request", 422),
    ],
)
def test_the_service_answers_each_code_with_its_status(code, status):
    error = format_error(FormatError("bad bytes", code), "sparse")
    assert (error.status_code, error.code, error.message) == (status, code, "sparse: bad bytes")


def test_the_client_reads_files_with_the_same_parsers(tmp_path):
    pickled = npy_bytes(np.array([{}], object), allow_pickle=True)
    with pytest.raises(InputError, match="never unpickles"):
        returns_list(pickled, None, (4, 4))
    eight_bit = cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes()
    with pytest.raises(InputError, match="single-channel 16-bit"):
        returns_list(eight_bit, None, (4, 4), depth_scale=0.001)
    write_returns_csv(tmp_path / "r.csv", np.array([[1, 2, 3.5]], np.float32))
    listed = returns_list(tmp_path / "r.csv", None, (4, 4))
    np.testing.assert_array_equal(listed, [[1, 2, 3.5]])
    with pytest.raises(InputError, match="or a CSV text file"):
        returns_list(b"row,col,z_m\n\xff\xfe\n", None, (4, 4))
