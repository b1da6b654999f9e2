"""Pinhole camera.

The camera looks from ``origin`` toward ``target``; ``up`` fixes the roll; ``fov`` is the
*vertical* field of view in degrees. Pixel (row 0, column 0) is the top-left of the image.
Fields are checked with :mod:`popvol.check` when the camera is made.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import check
from .errors import PopvolError

MAX_PIXELS = 8192 * 8192
#: Longest side of an image, in pixels.
MAX_SIDE = 65536
#: |coordinate| of the camera's origin and target, in world units: beyond the medium's limit
#: (medium.MAX_COORDINATE = 1e12), so that the automatic camera of any medium fits.
MAX_COORDINATE = 1e14


@dataclass
class Camera:
    origin: np.ndarray
    target: np.ndarray
    up: np.ndarray = (0.0, 1.0, 0.0)
    fov: float = 40.0
    width: int = 640
    height: int = 360
    source: str = "<camera>"

    def __post_init__(self):
        src = self.source
        self.origin = check.vector(self.origin, "camera.origin", src)
        self.target = check.vector(self.target, "camera.target", src)
        self.up = _unit(check.vector(self.up, "camera.up", src, nonzero=True))   # a direction: kept unit
        self.fov = check.number(self.fov, "camera.fov", src, 0.0, 180.0, open_interval=True)
        self.width = check.integer(self.width, "camera.width", src, 1, math.inf)
        self.height = check.integer(self.height, "camera.height", src, 1, math.inf)
        for name, side in (("camera.width", self.width), ("camera.height", self.height)):
            if side > MAX_SIDE:
                raise PopvolError(f"{src}: {name} = {side} must be at most {MAX_SIDE} pixels")
        for name, point in (("camera.target", self.target), ("camera.origin", self.origin)):
            if not np.abs(point).max() <= MAX_COORDINATE:
                raise PopvolError(f"{src}: {name} = {check._show(point)} must be within +-{MAX_COORDINATE:g} "
                                  "(world units) on every axis")
        with np.errstate(over="ignore", invalid="ignore"):
            view = self.target - self.origin
        if not np.all(np.isfinite(view)):
            raise PopvolError(f"{self.source}: camera.target - camera.origin overflows; "
                              "keep coordinates well below 1e308")
        if not view.any():
            raise PopvolError(f"{self.source}: camera.target equals camera.origin; they must differ")
        if not np.linalg.norm(np.cross(_unit(view), self.up)) >= 1e-9:
            raise PopvolError(f"{self.source}: camera.up is parallel to the view direction; choose another up vector")
        if self.width * self.height > MAX_PIXELS:
            raise PopvolError(f"{self.source}: camera {self.width}x{self.height} has more than {MAX_PIXELS} pixels")

    def basis(self) -> np.ndarray:
        """float64 (3, 3): rows forward, right, up (world space, unit, right-handed view)."""
        fwd = _unit(self.target - self.origin)
        right = _unit(np.cross(fwd, self.up))
        up = np.cross(right, fwd)
        return np.stack([fwd, right, up])

    def ray_directions(self, jitter: np.ndarray | None = None) -> np.ndarray:
        """Unit ray directions through pixel centres (or jittered positions), float64 (H, W, 3).

        ``jitter``: optional (H, W, 2) offsets in [-0.5, 0.5) pixels (x, y).
        """
        fwd, right, up = self.basis()
        tan_half = np.tan(np.radians(self.fov) / 2)
        aspect = self.width / self.height
        xs = np.arange(self.width) + 0.5
        ys = np.arange(self.height) + 0.5
        px, py = np.meshgrid(xs, ys)
        if jitter is not None:
            px = px + jitter[..., 0]
            py = py + jitter[..., 1]
        sx = (2 * px / self.width - 1) * tan_half * aspect
        sy = (1 - 2 * py / self.height) * tan_half
        d = fwd + sx[..., None] * right + sy[..., None] * up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _unit(v: np.ndarray) -> np.ndarray:
    """v / |v|, scaled by its largest component first so that neither a tiny (1e-320) nor a
    huge (1e308) vector under- or overflows; v must not be 0."""
    v = v / np.abs(v).max()
    return v / np.linalg.norm(v)
