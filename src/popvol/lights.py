"""Light sources.

A point light radiates intensity I [W/sr per RGB channel] equally in all directions from its
position; in vacuum its fluence at distance r is I / r^2.

A directional light (sun) is described by the direction its light *travels* (Mitsuba's
convention: a sun high in the sky has direction close to (0, -1, 0)) and its irradiance E
[W/m^2 per RGB channel] on a plane perpendicular to that direction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import PopvolError


def _floats(value, name: str, source: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PopvolError(f"{source}: light {name} must be numbers, got {value!r}") from None


def _rgb_power(value, name: str, source: str) -> np.ndarray:
    """float64 (3,) from 1 or 3 finite numbers >= 0 (a light's irradiance or intensity)."""
    e = _floats(value, name, source)
    if e.ndim == 0:
        e = np.full(3, float(e))
    if e.shape != (3,) or not np.all(np.isfinite(e)) or np.any(e < 0):
        raise PopvolError(f"{source}: light {name} must be 1 or 3 finite numbers >= 0, got {value!r}")
    return e


@dataclass
class DirectionalLight:
    """Collimated light from infinitely far away.

    Attributes:
        direction: float64 (3,), unit vector, the direction the light travels.
        irradiance: float64 (3,), RGB irradiance, >= 0.
        a0: anisotropy of the injected lobe about ``direction`` (1 = perfectly collimated).
        from_environment: one of the K lights an environment map was decomposed into (the
            reference export lights the scene with the map itself instead).
    """

    direction: np.ndarray
    irradiance: np.ndarray
    a0: float = 1.0
    source: str = "<light>"
    from_environment: bool = False

    def __post_init__(self):
        d = _floats(self.direction, "direction", self.source)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise PopvolError(f"{self.source}: light direction must be 3 finite numbers, not all zero, got {self.direction!r}")
        self.direction = d / np.linalg.norm(d)
        self.irradiance = _rgb_power(self.irradiance, "irradiance", self.source)
        if not (np.isfinite(self.a0) and 0.0 <= self.a0 <= 1.0):
            raise PopvolError(f"{self.source}: light a0 = {self.a0!r} is outside [0, 1]")
        self.a0 = float(self.a0)

    @property
    def power(self) -> np.ndarray:
        """What the renderer scales the per-unit fields by: the irradiance."""
        return self.irradiance


@dataclass
class PointLight:
    """An isotropic point light.

    Attributes:
        position: float64 (3,), world position.
        intensity: float64 (3,), RGB radiant intensity [W/sr], >= 0.
    """

    position: np.ndarray
    intensity: np.ndarray
    source: str = "<light>"
    a0: float = 1.0                 # light leaves the point radially: a collimated radial lobe
    from_environment: bool = False

    def __post_init__(self):
        p = _floats(self.position, "position", self.source)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise PopvolError(f"{self.source}: light position must be 3 finite numbers, got {self.position!r}")
        self.position = p
        self.intensity = _rgb_power(self.intensity, "intensity", self.source)

    @property
    def power(self) -> np.ndarray:
        """What the renderer scales the per-unit fields by: the intensity."""
        return self.intensity
