"""Image formation on the CPU: the projector's light from its image, and the camera that develops a photo.

Projector: pixel value v (0..255) → light black + (1 − black)·(v/255)^γ, blurred by its lens and by
defocus (a thin-lens blur circle c = aperture · f_px · |1/s − 1/z|, Gaussian σ = c/4). The shader picks the
blur per fragment from a few pre-blurred levels.

Camera: radiance (cd/m²) and depth on the sensor grid (the renderer draws an enlarged pinhole, warped by the
lens distortion of render.distortion) are blurred by lens and defocus, dimmed by cos⁴ vignetting,
turned into electrons (exposure · responsivity · a fixed per-pixel response, PRNU), given shot and read
noise, clipped at full well, gamma encoded and quantised to 8 bits. A colour camera is a Bayer sensor: each
pixel sees one of red, green, blue through an RGGB filter mosaic, the noise is that pixel's, and the photo's
three channels are interpolated from the mosaic (OpenCV's edge-aware demosaicing) before the gamma — so a
colour photo has the colour fringes and the per-channel noise of a real one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from render.distortion import DistortionMap, distortion_map, undistorted_directions

LUMA_RGB = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)   # Rec. 709 luminance weights
BLUR_LEVEL_RATIO = 2.0            # successive blur levels differ by this factor in σ
BLUR_LEVEL_SKIP_PX = 0.05         # a level this close to the previous one is not worth blurring for
UNIFORM_DISC_SIGMA = 0.25         # Gaussian σ of a uniform disc, per unit diameter
AUTO_EXPOSURE_PERCENTILE = 99.5   # auto exposure meters on this percentile of the scene's radiance …
AUTO_EXPOSURE_LEVEL = 0.75        # … and puts it at this fraction of full well
AUTO_EXPOSURE_MAX_GAIN = 4.0      # never longer than this many times the configured exposure
DISTORTION_SUPERSAMPLE = 2        # a distorting camera's view: rendered this much finer per side (see to_sensor)


def defocus_sigma_px(aperture_mm: float, f_px: float, focus_m: float, depth_m: NDArray | float,
                     lens_blur_px: float) -> NDArray | float:
    """Total blur σ (pixels) at depth: lens blur and the thin-lens defocus circle, combined in quadrature."""
    with np.errstate(divide="ignore"):
        circle = aperture_mm * 1e-3 * f_px * np.abs(1.0 / focus_m - 1.0 / np.maximum(depth_m, 1e-6))
    return np.sqrt(lens_blur_px**2 + (UNIFORM_DISC_SIGMA * circle) ** 2)


def blur_levels(sigma_min: float, sigma_max: float) -> tuple[float, ...]:
    """Ascending σ levels from sigma_min covering sigma_max, a factor BLUR_LEVEL_RATIO apart."""
    levels = [float(sigma_min)]
    while levels[-1] + BLUR_LEVEL_SKIP_PX < sigma_max and len(levels) < 8:
        levels.append(max(levels[-1] * BLUR_LEVEL_RATIO, levels[-1] + 0.5))
    return tuple(levels)


def luma(rgb: NDArray[np.float32]) -> NDArray[np.float32]:
    """(h, w, 3) → (h, w) Rec. 709 luminance; also (h, w, 4), the fourth channel ignored (cv2.transform: one
    pass, where numpy's matmul makes copies)."""
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4) or rgb.dtype != np.float32:
        return np.asarray(rgb[..., :3] @ LUMA_RGB, dtype=np.float32)
    weights = LUMA_RGB if rgb.shape[2] == 3 else np.append(LUMA_RGB, np.float32(0.0))
    return cv2.transform(np.ascontiguousarray(rgb), weights.reshape(1, -1))


def standard_normal(rng: np.random.Generator, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Standard normal float32 noise, reproducible from rng: OpenCV's generator seeded from it, about 4x
    faster than numpy's for a photo's million samples (its statistics checked in tests/arproj/sim)."""
    out = np.empty(shape, dtype=np.float32)
    cv2.setRNGSeed(int(rng.integers(1, 2**31 - 1)))
    # A 2-D single-channel view: OpenCV would read a trailing 3 as colour channels with per-channel σ.
    cv2.randn(out.reshape(shape[0] if len(shape) else 1, -1), 0.0, 1.0)
    return out


def gaussian(image: NDArray[np.float32], sigma: float) -> NDArray[np.float32]:
    if sigma < 0.05:
        return image
    return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)


def projector_light(image: NDArray, intr: Intrinsics, gamma: float, contrast_ratio: float,
                    levels: tuple[float, ...]) -> NDArray[np.float32]:
    """(L, h, w) or (L, h, w, 3) float32 linear light (1 = full white) of a projector image, one layer per
    blur σ (grey images stay single-channel).

    image : (h, w) or (h, w, 3) uint8 (or float 0..1) at the projector's resolution.
    """
    img = np.asarray(image)
    if img.shape[:2] != (intr.height, intr.width) or img.ndim not in (2, 3) or (
            img.ndim == 3 and img.shape[2] not in (1, 3)):
        raise InputError(f"projector image has shape {img.shape}; the projector needs "
                         f"({intr.height}, {intr.width}) or ({intr.height}, {intr.width}, 3)")
    black = 1.0 / contrast_ratio
    if img.dtype == np.uint8:
        lut = (black + (1.0 - black) * (np.arange(256) / 255.0) ** gamma).astype(np.float32)
        light = lut[img]
    elif np.issubdtype(img.dtype, np.floating):
        light = (black + (1.0 - black) * np.clip(img, 0.0, 1.0) ** gamma).astype(np.float32)
    else:
        raise InputError(f"projector image must be uint8 (0..255) or float (0..1), got {img.dtype}")
    if light.ndim == 3 and light.shape[2] == 1:
        light = light[..., 0]
    return np.stack([gaussian(np.ascontiguousarray(light), s) for s in levels])


GAMMA_LUT_SIZE = 4096   # gamma through a lookup table: fast, and far below one 8-bit step of error
# RGGB: red at even rows and columns, blue at odd ones, green between (OpenCV 5 names the pattern as it is).
BAYER_DEMOSAIC = cv2.COLOR_BayerRGGB2RGB_EA


def bayer_mosaic(rgb: NDArray[np.float32]) -> NDArray[np.float32]:
    """(h, w) what an RGGB sensor's pixels see of (h, w, 3) light: each pixel the channel of its filter."""
    out = np.ascontiguousarray(rgb[..., 1])
    out[0::2, 0::2] = rgb[0::2, 0::2, 0]
    out[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return out


def demosaic(mosaic: NDArray[np.uint16]) -> NDArray[np.uint16]:
    """(h, w, 3) RGB interpolated from an RGGB mosaic (h, w) of linear codes."""
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(mosaic), BAYER_DEMOSAIC), dtype=np.uint16)


@lru_cache(maxsize=8)
def _gamma_lut(gamma: float) -> NDArray[np.uint8]:
    return np.rint(255.0 * (np.arange(GAMMA_LUT_SIZE + 1) / GAMMA_LUT_SIZE) ** (1.0 / gamma)).astype(np.uint8)


@lru_cache(maxsize=8)
def vignetting_gain(intr: Intrinsics) -> NDArray[np.float32]:
    """(h, w) natural cos⁴ fall-off of every pixel's ray (1 on the axis)."""
    xy = undistorted_directions(intr)
    return ((1.0 + (xy**2).sum(axis=2)) ** -2.0).astype(np.float32)


@dataclass
class CameraModel:
    """A camera's optics and sensor (scene section `cameras`) with its intrinsics."""

    intr: Intrinsics
    color: bool
    exposure_s: float
    responsivity: float
    full_well_e: float
    read_noise_e: float
    gamma: float
    aperture_mm: float
    focus_distance_m: float
    lens_blur_px: float
    vignetting: bool
    prnu: float = 0.0
    pixel_gain: NDArray[np.float32] | None = None   # (h, w) fixed per-pixel response (PRNU), drawn once
    _gain_cache: tuple[float, NDArray[np.float32] | float] | None = field(default=None, repr=False,
                                                                         compare=False)

    @classmethod
    def from_config(cls, intr: Intrinsics, c: dict, rng: np.random.Generator) -> CameraModel:
        """The camera of scene section `cameras`; rng draws its fixed pixel-response pattern."""
        prnu = float(c["prnu"])
        gain = None
        if prnu > 0:
            gain = (1.0 + prnu * rng.standard_normal((intr.height, intr.width))).astype(np.float32)
        return cls(intr, bool(c["color"]), float(c["exposure_s"]), float(c["responsivity"]),
                   float(c["full_well_e"]), float(c["read_noise_e"]), float(c["gamma"]),
                   float(c["aperture_mm"]), float(c["focus_distance_m"]), float(c["lens_blur_px"]),
                   bool(c["vignetting"]), prnu, gain)

    @property
    def render_scale(self) -> int:
        """Rendered pixels per sensor pixel (per side): DISTORTION_SUPERSAMPLE when the lens distorts, else 1."""
        return DISTORTION_SUPERSAMPLE if self.intr.has_distortion else 1

    @property
    def render_intrinsics(self) -> Intrinsics:
        """The pinhole the renderer draws: enlarged to hold every ray when the lens distorts (and finer, see
        to_sensor)."""
        return self.dmap.pinhole if self.intr.has_distortion else self.intr

    @property
    def dmap(self) -> DistortionMap:
        """The distortion map onto the sensor sampled render_scale times finer."""
        return distortion_map(self.intr.scaled(self.render_scale))

    def to_sensor(self, rendered: NDArray[np.float32]) -> NDArray[np.float32]:
        """A render of render_intrinsics (h', w'[, c]) on the sensor grid: through the lens distortion, each sensor
        pixel the mean over its area (render_scale² samples). One sample at each pixel's centre, bilinear in
        the pinhole render, left every board corner a few hundredths of a pixel off in a pattern that follows
        the distortion: a stereo calibration's principal points came out +0.42 px on average (16 board views,
        12 seeds), +0.27 px with the area mean (+0.03 px with a plain linear sensor; the rest is not located)."""
        if not self.intr.has_distortion:
            return rendered
        m = self.dmap.map_xy
        fine = cv2.remap(rendered, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        if self.render_scale == 1:
            return fine
        return cv2.resize(fine, (self.intr.width, self.intr.height), interpolation=cv2.INTER_AREA)

    def develop(self, rendered: NDArray[np.float32], exposure_s: float | None, rng: np.random.Generator | None
                ) -> NDArray[np.uint8]:
        """The 8-bit photo from the renderer's pinhole (H', W', 4) radiance + depth; rng None: no noise."""
        img = self.to_sensor(rendered)
        signal = img[..., :3] if self.color else img[..., :3] @ LUMA_RGB
        return self.expose(np.ascontiguousarray(signal), img[..., 3], exposure_s, rng)

    def metered_exposure(self, radiance: NDArray[np.float32]) -> float:
        """Auto exposure (s): the brightest part of the scene (99.5th percentile) at AUTO_EXPOSURE_LEVEL of
        full well, never longer than AUTO_EXPOSURE_MAX_GAIN × the configured exposure."""
        signal = radiance if radiance.ndim == 2 else radiance @ LUMA_RGB
        lit = signal[signal > 0]
        if lit.size == 0:
            return self.exposure_s
        bright = float(np.percentile(lit, AUTO_EXPOSURE_PERCENTILE))
        exposure = AUTO_EXPOSURE_LEVEL * self.full_well_e / (bright * self.responsivity)
        return float(min(exposure, AUTO_EXPOSURE_MAX_GAIN * self.exposure_s))

    def expose(self, radiance: NDArray[np.float32], depth: NDArray[np.float32], exposure_s: float | None,
               rng: np.random.Generator | None, plan: BlurPlan | None = None) -> NDArray[np.uint8]:
        """The 8-bit photo from radiance on the sensor grid ((h, w) mono or (h, w, 3) colour, cd/m²) and depth
        (h, w) metres (0: nothing): defocus, vignetting, exposure, (colour: the Bayer mosaic), shot and read
        noise, clipping, (colour: demosaicing), gamma. plan: the defocus blur for this depth, if already worked
        out (blur_plan)."""
        exposure = self.exposure_s if exposure_s is None else float(exposure_s)
        if not exposure > 0:
            raise InputError(f"exposure = {exposure_s!r} s must be positive")
        signal = (plan or self.blur_plan(depth)).apply(radiance)
        colour = signal.ndim == 3
        if colour:
            signal = bayer_mosaic(signal)
        electrons = np.multiply(signal, self._gain(exposure), dtype=np.float32)  # a new array: in place below
        if rng is not None:
            noise = standard_normal(rng, electrons.shape)
            sigma = np.maximum(electrons, np.float32(0.0))
            sigma += np.float32(self.read_noise_e**2)
            np.sqrt(sigma, out=sigma)
            noise *= sigma
            electrons += noise
        electrons *= np.float32(GAMMA_LUT_SIZE / self.full_well_e)
        electrons += np.float32(0.5)
        # NaN (no light defined, e.g. outside every surface) is dark: clip keeps NaN, and casting NaN to an
        # integer is undefined (numpy's "invalid value encountered in cast").
        np.nan_to_num(electrons, copy=False, nan=0.0)
        np.clip(electrons, 0.0, GAMMA_LUT_SIZE, out=electrons)
        codes = electrons.astype(np.uint16)
        return np.take(_gamma_lut(self.gamma), demosaic(codes) if colour else codes)

    def _gain(self, exposure: float) -> NDArray[np.float32] | float:
        """Electrons per (cd/m²) at every pixel: exposure · responsivity · vignetting · PRNU (cached)."""
        cached = self._gain_cache
        if cached is not None and cached[0] == exposure:
            return cached[1]
        gain: NDArray[np.float32] | float = exposure * self.responsivity
        if self.vignetting:
            gain = gain * vignetting_gain(self.intr)
        if self.pixel_gain is not None:
            gain = gain * self.pixel_gain
        if np.ndim(gain):
            gain = np.asarray(gain, dtype=np.float32)
        self._gain_cache = (exposure, gain)
        return gain

    def blur_plan(self, depth: NDArray[np.float32]) -> BlurPlan:
        """Lens + depth-dependent defocus as a blend of a few Gaussian levels, weights per pixel by depth."""
        valid = depth > 0
        if not valid.any():
            return BlurPlan((self.lens_blur_px,), [None])
        # σ grows away from the focus distance, so the depth extremes bound it: often one level is enough.
        extremes = np.array([depth[valid].min(), depth.max()])
        bound = defocus_sigma_px(self.aperture_mm, self.intr.fx, self.focus_distance_m, extremes,
                                 self.lens_blur_px)
        levels = blur_levels(self.lens_blur_px, float(np.max(bound)))
        if len(levels) == 1:
            return BlurPlan(levels, [None])
        sigma = defocus_sigma_px(self.aperture_mm, self.intr.fx, self.focus_distance_m,
                                 np.where(valid, depth, self.focus_distance_m), self.lens_blur_px)
        sig = np.asarray(levels, dtype=np.float32)
        position = np.interp(sigma, sig, np.arange(len(sig), dtype=np.float32)).astype(np.float32)
        weights = [np.clip(1.0 - np.abs(position - k), 0.0, 1.0) for k in range(len(levels))]
        used = [k for k, w in enumerate(weights) if w.any()]
        return BlurPlan(tuple(levels[k] for k in used), [weights[k] for k in used])


@dataclass
class BlurPlan:
    """Gaussian σ levels (pixels) and per-pixel (h, w) weights that blend them (None: a single level)."""

    levels: tuple[float, ...]
    weights: list[NDArray[np.float32] | None]

    def apply(self, signal: NDArray[np.float32]) -> NDArray[np.float32]:
        if len(self.levels) == 1:
            return gaussian(signal, self.levels[0])
        out = np.zeros_like(signal)
        for s, weight in zip(self.levels, self.weights, strict=True):
            assert weight is not None
            out += gaussian(signal, s) * (weight[..., None] if signal.ndim == 3 else weight)
        return out
