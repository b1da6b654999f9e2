"""Pinhole camera.

The camera looks from ``origin`` toward ``target``; ``up`` fixes the roll; ``fov`` is the
*vertical* field of view in degrees. Pixel (row 0, column 0) is the top-left of the image.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import PopvolError

MAX_PIXELS = 8192 * 8192


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
        for name in ("origin", "target", "up"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise PopvolError(f"{self.source}: camera.{name} must be 3 finite numbers, got {getattr(self, name)!r}")
            setattr(self, name, v)
        if np.linalg.norm(self.target - self.origin) == 0:
            raise PopvolError(f"{self.source}: camera.target equals camera.origin; they must differ")
        if np.linalg.norm(np.cross(self.target - self.origin, self.up)) < 1e-9 * np.linalg.norm(self.target - self.origin) * max(np.linalg.norm(self.up), 1e-300):
            raise PopvolError(f"{self.source}: camera.up is parallel to the view direction; choose another up vector")
        if not (np.isfinite(self.fov) and 0.0 < self.fov < 180.0):
            raise PopvolError(f"{self.source}: camera.fov = {self.fov!r} degrees is outside (0, 180)")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise PopvolError(f"{self.source}: camera.{name} = {v!r} must be an integer >= 1")
        if self.width * self.height > MAX_PIXELS:
            raise PopvolError(f"{self.source}: camera {self.width}x{self.height} has more than {MAX_PIXELS} pixels")
        self.fov = float(self.fov)
        self.width, self.height = int(self.width), int(self.height)

    def basis(self) -> np.ndarray:
        """float64 (3, 3): rows forward, right, up (world space, unit, right-handed view)."""
        fwd = self.target - self.origin
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
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
