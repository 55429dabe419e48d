"""What a camera does to the light it gets: blur, exposure, noise, bit depth, encoding.

The renderer gives linear radiance (1 = a white surface lit by the Sun at normal incidence);
``expose`` turns it into the image a user sends: the optics' blur (a Gaussian PSF and, on some
cameras, a defocus disc), vignetting, the exposure (where a lit white surface lands, from 10 %
of full scale, under-exposed, to 6 times full scale, over-exposed and clipped), photon shot
noise and read noise, the transfer curve (gamma or linear), and the digital number: 8 bits,
or 12 and 16 bits in a 16-bit image (a 12-bit camera's values either shifted to the top of the
16 bits or left in 0-4095, both of which users send), and JPEG compression of 8-bit frames.
Every factor is drawn per frame (``sample_sensor``) and recorded (``Sensor.metadata``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np

SENSOR_KINDS = ("paper", "any")


@dataclass(frozen=True)
class Sensor:
    """One camera's electronics and optics blur. Pixels for lengths, fractions of full scale
    for signal levels."""

    psf_sigma_px: float  # Gaussian blur of the optics, 1 sigma
    defocus_px: float  # radius of a defocus disc; 0 = in focus
    vignetting: float  # light lost in the corners, fraction (0 = none)
    exposure: float  # the full-scale fraction a lit white surface reaches (> 1: clipped)
    full_well_e: float  # electrons at full scale: sets the shot noise
    read_noise: float  # 1 sigma, fraction of full scale
    bits: int  # 8, 12 or 16
    msb_aligned: bool  # 12 bits stored in 16: shifted to the top (True) or in 0-4095 (False)
    gamma: float  # transfer curve exponent; 1 = linear (raw)
    jpeg_quality: int  # 8-bit frames only; 0 = not compressed

    def metadata(self) -> dict:
        return {k: round(v, 5) if isinstance(v, float) else v for k, v in asdict(self).items()}


def paper_sensor(rng: np.random.Generator, width: int) -> Sensor:
    """The paper-like camera the first datasets used: 8 bits, sRGB-like or linear, mild blur,
    well exposed (white paint, albedo 0.8, lit at normal incidence at 50-160 % of full scale)."""
    return Sensor(
        psf_sigma_px=float(rng.uniform(0.3, 1.2) * width / 1024),
        defocus_px=0.0,
        vignetting=0.0,
        exposure=float(rng.uniform(0.5, 1.6) / 0.8),
        full_well_e=float(rng.uniform(5000, 20000)),
        read_noise=float(rng.uniform(0.3, 2.5) / 255),
        bits=8,
        msb_aligned=True,
        gamma=float(rng.choice([2.2, 2.2, 1.8, 1.0])),
        jpeg_quality=0,
    )


def any_sensor(rng: np.random.Generator) -> Sensor:
    """A camera from the range flight cameras span: any of the factors above."""
    bits = int(rng.choice([8, 12, 16], p=[0.55, 0.25, 0.2]))
    linear = rng.random() < (0.3 if bits == 8 else 0.8)
    return Sensor(
        psf_sigma_px=float(rng.uniform(0.3, 2.0)),
        defocus_px=float(rng.uniform(1.0, 4.0)) if rng.random() < 0.2 else 0.0,
        vignetting=float(rng.uniform(0.0, 0.35)),
        exposure=float(math.exp(rng.uniform(math.log(0.1), math.log(6.0)))),
        full_well_e=float(math.exp(rng.uniform(math.log(2000), math.log(40000)))),
        read_noise=float(math.exp(rng.uniform(math.log(3e-4), math.log(1e-2)))),
        bits=bits,
        msb_aligned=bool(rng.random() < 0.5),
        gamma=1.0 if linear else float(rng.choice([2.2, 1.8])),
        jpeg_quality=int(rng.integers(40, 96)) if bits == 8 and rng.random() < 0.25 else 0,
    )


def sample_sensor(rng: np.random.Generator, width: int, kind: str = "any") -> Sensor:
    """A sensor of ``kind`` (``SENSOR_KINDS``) for a camera ``width`` pixels wide."""
    if kind == "paper":
        return paper_sensor(rng, width)
    if kind == "any":
        return any_sensor(rng)
    raise ValueError(f"unknown sensor kind {kind!r}; choose one of {SENSOR_KINDS}")


def _blur(signal: np.ndarray, sensor: Sensor) -> np.ndarray:
    """The optics: a defocus disc (pillbox), then the Gaussian PSF."""
    if sensor.defocus_px > 0:
        r = sensor.defocus_px
        size = 2 * math.ceil(r) + 1
        yy, xx = np.mgrid[:size, :size] - size // 2
        disc = (np.hypot(xx, yy) <= r + 0.5).astype(np.float64)
        signal = cv2.filter2D(signal, -1, disc / disc.sum(), borderType=cv2.BORDER_REFLECT)
    return cv2.GaussianBlur(signal, (0, 0), sensor.psf_sigma_px)


def _vignette(shape: tuple[int, int], strength: float) -> np.ndarray:
    """Relative illumination: 1 at the centre, 1 - ``strength`` in the corners (cos^4-like)."""
    h, w = shape
    yy, xx = np.ogrid[:h, :w]
    r2 = ((xx - (w - 1) / 2) / (w / 2)) ** 2 + ((yy - (h - 1) / 2) / (h / 2)) ** 2
    return 1.0 - strength * r2 / 2.0


def _digitise(encoded: np.ndarray, sensor: Sensor) -> np.ndarray:
    """[0, 1] values -> the image's digital numbers (uint8, or uint16 holding 12/16 bits)."""
    levels = 2**sensor.bits - 1
    dn = np.clip(np.round(encoded * levels), 0, levels)
    if sensor.bits == 8:
        return dn.astype(np.uint8)
    if sensor.bits == 12 and sensor.msb_aligned:
        dn = dn * 16
    return dn.astype(np.uint16)


def _jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("OpenCV could not encode a JPEG")
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)


def expose(radiance: np.ndarray, sensor: Sensor, rng: np.random.Generator) -> np.ndarray:
    """The image (H, W) uint8 or uint16 a camera with ``sensor`` makes of linear ``radiance``
    (H, W)."""
    signal = np.clip(radiance.astype(np.float64), 0, None) * sensor.exposure
    signal = _blur(signal, sensor)
    if sensor.vignetting > 0:
        signal *= _vignette(signal.shape, sensor.vignetting)
    # far past saturation all clips; the blur's rounding can leave tiny negative values
    electrons = np.clip(signal, 0.0, 4.0) * sensor.full_well_e
    signal = rng.poisson(electrons) / sensor.full_well_e
    encoded = np.clip(signal, 0, 1) ** (1 / sensor.gamma)
    encoded = encoded + rng.normal(0, sensor.read_noise, encoded.shape)
    image = _digitise(encoded, sensor)
    return _jpeg(image, sensor.jpeg_quality) if sensor.jpeg_quality else image
