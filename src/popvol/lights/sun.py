"""A directional light (a sun) and its domain: a rectilinear grid whose first axis is the
direction the light travels (docs/METHOD.md, "Walk").

The light is described by the direction its light *travels* (Mitsuba's convention: a sun high
in the sky has direction close to (0, -1, 0)) and its irradiance E [W/m^2 per RGB channel] on a
plane perpendicular to that direction. Its domain is walked once for unit irradiance.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .. import check
from ..domains import DirectionalDomain, directional_domain, resample_medium
from ..method import knob_field
from ..errors import PopvolError
from ..kernels.sampling import domain_to_world
from ..walk import (default_max_iterations, direct_fluence, handover_factor, medium_factors, scatter_factor,
                    walk_box, walk_the_tail)
from .base import HandOver, Light

#: the eighteen-ordinate walk's tail (method.tail) is walked on blocks of TAIL_FACTOR^3 of its cells
TAIL_FACTOR = 2


@dataclass
class DirectionalLight(Light):
    """Collimated light from infinitely far away.

    Attributes:
        direction: float64 (3,), unit vector, the direction the light travels.
        irradiance: float64 (3,), RGB irradiance, >= 0.
        a0: anisotropy of the injected lobe about ``direction`` (1 = perfectly collimated).
        from_environment: one of the K lights an environment map was decomposed into (the
            reference export lights the scene with the map itself instead).
        map_region: one of the median-cut regions of that map (not its sun): the gathered
            last bounce takes this light's first scattering from the map itself, its texels
            (``texels``, bool (H, W)) scaled by the light's power over theirs
            (renderer.gathered_environment).
    """

    type: ClassVar[str] = "directional"
    keys: ClassVar[frozenset] = frozenset({"type", "direction", "irradiance", "a0"})
    power_field: ClassVar[str] = "irradiance"

    direction: np.ndarray
    irradiance: np.ndarray
    a0: float = 1.0
    source: str = "<light>"
    from_environment: bool = False
    map_region: bool = False
    texels: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self):
        d = check.vector(self.direction, *self.field("direction"), nonzero=True)
        d = d / np.abs(d).max()             # so that neither [1e308, 1e308, 0] nor [1e-320, 0, 0] over- or underflows
        self.direction = d / np.linalg.norm(d)
        self.irradiance = check.power(self.irradiance, *self.field("irradiance"))
        self.a0 = check.number(self.a0, *self.field("a0"), 0.0, 1.0)

    @classmethod
    def from_table(cls, t: dict, name: str, src: str) -> "DirectionalLight":
        if "direction" not in t:
            raise PopvolError(f"{src}: {name}.direction is required (the direction the light travels)")
        return cls(t["direction"], t.get("irradiance", 1.0), t.get("a0", 1.0), source=f"{src}: {name}")

    @property
    def render_direction(self) -> np.ndarray:
        return self.direction

    @property
    def unscattered(self) -> bool:
        return self.a0 == 1.0           # a broad lobe (an environment's light) has no direct field

    def key(self) -> tuple:
        # rounded: normalising an already unit direction again may change its last bit
        return ("directional", tuple(np.round(self.direction, 12)), self.a0, self.from_environment)

    def domain(self, medium, method) -> "SunDomain":
        knob = "environment_resolution" if self.from_environment and method.environment_resolution else "resolution"
        resolution = getattr(method, knob)
        grid = directional_domain(medium, self.direction, resolution, diffusion_factor(resolution, method),
                                  field=knob_field(method, knob, medium.source))
        return SunDomain(grid.frame, grid.origin, grid.h, grid.shape, grid.block, self.a0)

    def table(self) -> dict:
        return {"type": self.type, "direction": [float(x) for x in self.direction],
                "irradiance": [float(x) for x in self.irradiance], "a0": float(self.a0)}

    def mitsuba(self) -> dict:
        return {"type": "directional", "direction": self.direction.tolist(),
                "irradiance": {"type": "rgb", "value": self.irradiance.tolist()}}

    def digest(self) -> bytes:
        return np.concatenate([self.direction, self.irradiance]).astype(np.float64).tobytes()


def diffusion_factor(resolution: int, method) -> int:
    """Domain cells per diffusion cell along each axis for a domain of ``resolution`` cells
    along its lattice's longest side: the diffusion grid has about method.diffusion_resolution
    cells there (0: the domain's own)."""
    if not method.diffusion_resolution:
        return 1
    return max(1, round(resolution / method.diffusion_resolution))


@dataclass
class SunDomain(DirectionalDomain):
    """A sun's domain: a light-aligned DirectionalDomain and the anisotropy a0 of the light
    injected through its face k = 0."""

    a0: float = 1.0

    @property
    def unscattered(self) -> bool:
        """Whether the domain keeps its light's unscattered part apart (a direct field): a
        collimated sun does; a broad lobe (a0 < 1, an environment's light) does not."""
        return self.a0 == 1.0

    def resample(self, medium, channel: int = 0):
        return resample_medium(medium, self, channel)

    def walk(self, optics, method, progress=None, read=None):
        """Walk unit irradiance from the face k = 0 (E h^2 per cell of slice 0); with the
        diffusion stage, packets hand over at ``method.handover_scale`` times the cell's
        :func:`handover_factor`, or at ``method.environment_handover_scale`` times it for a
        broad lobe (a0 < 1), which has no direct field. The six-ordinate walk carries every
        order itself: no hand-over (docs/METHOD.md, "Six ordinates"); it crosses the empty
        cells outside ``read`` (:meth:`cells_read`; None: every cell read) without visiting
        them. The eighteen-ordinate walk walks its faint packets and its last light (below
        ``method.tail`` in flight) on blocks of TAIL_FACTOR^3 cells (walk.walk_the_tail)."""
        sigma_t, sigma_s, g = optics
        Th, Dh = medium_factors(sigma_t, sigma_s, g, self.h, method.decay)
        handover = None
        if method.isotropic == "diffusion" and method.solver != "ordinates":   # six ordinates walk it all
            # a broad lobe (an environment's light) has no direct field: its single scattering is
            # the walk's, so it is handed over later (docs/METHOD.md, "Hand-over")
            scale = method.handover_scale if self.unscattered else method.environment_handover_scale
            handover = (scale, handover_factor(sigma_t, sigma_s, g, self.h))
        injection = np.full(self.shape[1:], self.h * self.h, np.float32)
        scatter = scatter_factor(sigma_s, self.h) if method.solver == "ordinates" else None
        result = walk_box(Th, Dh, injection, self.a0, self.h, method.rule, method.solver,
                          method.tolerance, method.max_iterations, progress=progress, handover=handover,
                          scatter=scatter, read=read, ordinates=method.ordinates,
                          tail=(method.tail if method.solver == "ordinates" else 0.0, TAIL_FACTOR))
        if result.pending is not None:
            # its last light walked on cells TAIL_FACTOR times as wide (docs/METHOD.md, "The
            # walk's tail on wider cells")
            walk_the_tail(result, optics, self.h, self.a0, read, TAIL_FACTOR, method.tolerance, method.decay,
                          method.max_iterations or default_max_iterations(self.shape, "ordinates"))
        if self.unscattered or method.solver == "ordinates":
            # a broad lobe's unscattered part, kept apart from the ordinates' walked light for the
            # gathered last bounce (docs/METHOD.md Eq. 26a)
            result.direct, result.direct_a0 = self.direct_fluence(sigma_t), self.a0
        return result

    def direct_fluence(self, sigma_t):
        """The unscattered fluence of the injected light at the cell centres per unit irradiance
        (float32, the domain's shape; Eq. 22): a collimated sun's, lit with its own lobe by the
        renderer, or a broad lobe's (a0 < 1, an environment's light), Beer-Lambert along d."""
        return direct_fluence(sigma_t, self.h)

    def hand_over(self, walk, optics, medium, method, channel: int = 0) -> HandOver:
        """The diffusion grid is the domain itself, in blocks of diffusion_factor^3 cells."""
        return HandOver(self, walk.handed[0], walk.handed[1], optics, self.block)

    def world_fields(self, walk, medium, needed, outs, also=()) -> None:
        fields = (walk.phi, walk.phia) + (() if walk.direct is None else (walk.direct,))
        outs = tuple(outs[:len(fields)])
        for field, out in also:          # one stencil per voxel serves them all
            fields, outs = fields + (field,), outs + (out,)
        domain_to_world(fields, self.frame, self.origin, self.h, medium.origin, medium.voxel_size, outs, needed)
