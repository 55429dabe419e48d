import math

import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA, GivenIntrinsics, Intrinsics


def test_intrinsics_derive_from_table_1():
    K = PAPER_CAMERA.intrinsics()
    assert K.fx == pytest.approx(50 * 1024 / 6.449)
    assert K.fx == pytest.approx(7939.2, abs=0.1)
    assert (K.cx, K.cy) == (511.5, 511.5)
    assert PAPER_CAMERA.fov_deg == pytest.approx(7.38, abs=0.01)


def test_scaled_intrinsics_keep_the_field_of_view():
    K = PAPER_CAMERA.intrinsics()
    half = K.scaled(512, 512)
    assert half.fx == pytest.approx(K.fx / 2)
    assert (half.cx, half.cy) == (255.5, 255.5)
    # the image edge sees the same angle at both resolutions
    assert math.atan((0 - 0.5 - half.cx) / half.fx) == pytest.approx(
        math.atan((-0.5 - K.cx) / K.fx)
    )


def test_project_inverts_pixel_rays():
    K = PAPER_CAMERA.intrinsics()
    u, v = np.array([0.0, 100.0, 1023.0]), np.array([5.0, 700.0, 1023.0])
    points = K.pixel_rays(u, v) * 123.0
    pu, pv = K.project(points)
    np.testing.assert_allclose(pu, u)
    np.testing.assert_allclose(pv, v)


def test_a_focal_length_given_alone_keeps_the_defaults_pixel_aspect():
    """fx alone (a careless client's "the focal length is 1400 px") is no anisotropic camera:
    the other focal length follows at the default's ratio, not at the default lens's value."""
    base = Intrinsics(1000.0, 1010.0, 511.5, 383.5, 1024, 768)
    assert GivenIntrinsics(fx=2000.0).over(base) == Intrinsics(
        2000.0, 2020.0, 511.5, 383.5, 1024, 768
    )
    assert GivenIntrinsics(fy=505.0, cx=500.0).over(base) == Intrinsics(
        500.0, 505.0, 500.0, 383.5, 1024, 768
    )
    assert GivenIntrinsics(fx=1.0, fy=2.0).over(base).fy == 2.0  # both given: as given
    square = PAPER_CAMERA.intrinsics().scaled(1024, 1024)
    assert GivenIntrinsics(fx=1400.0).over(square).fy == pytest.approx(1400.0)
    # over other given values without both focal lengths: value by value
    assert GivenIntrinsics(fx=3.0).over(GivenIntrinsics(fy=4.0)) == GivenIntrinsics(fx=3.0, fy=4.0)


def test_given_intrinsics_fill_in_value_by_value():
    K = PAPER_CAMERA.intrinsics().scaled(256, 256)
    given = GivenIntrinsics.from_dict({"fx": "900", "cy": 100, "cx": None, "width": 7})
    assert given == GivenIntrinsics(fx=900.0, cy=100.0)
    assert given.pinhole_dict() == {"fx": 900.0, "cy": 100.0}
    assert given.over(K) == Intrinsics(900.0, 900.0 * K.fy / K.fx, K.cx, 100.0, 256, 256)
    assert GivenIntrinsics(cx=5.0).over(given) == GivenIntrinsics(fx=900.0, cx=5.0, cy=100.0)
    assert not given.whole and GivenIntrinsics.from_dict(K.as_dict()).whole
    assert Intrinsics(**K.as_dict()) == Intrinsics.from_matrix(K.matrix(), 256, 256) == K
    assert K.describe(1) == f"fx {K.fx:.1f} fy {K.fy:.1f} cx 127.5 cy 127.5"
