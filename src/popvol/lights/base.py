"""The light interface: what every kind of light gives the scene loader, the pipeline, the
renderer and the Mitsuba export.

A light is plain data (its position or direction and its RGB power) plus its *domain*: the grid
of cells, aligned with the light's principal ordinate, in which its light is walked
(docs/METHOD.md, "Walk"). The pipeline (popvol.pipeline) runs the same steps for every kind::

    domain = light.domain(medium, method)               # build
    sigma_t, sigma_s, g = domain.resample(medium, ch)   # the medium at its cells
    walk = domain.walk((sigma_t, sigma_s, g), method)   # phi, phi a, direct, handed-over light
    hand = domain.hand_over(walk, optics, medium, ...)  # to a rectilinear diffusion grid
    ... diffusion, budget (the same code for every kind) ...
    domain.world_fields(walk, medium, needed, outs)     # the renderer's fields

Adding a kind of light is one new module beside sun.py and point.py holding the light's class
(a subclass of :class:`Light`, registered in lights/__init__.py under its TOML ``type``) and its
domain (a :class:`LightDomain`), plus its tests. If the renderer must look its fields up in
its own domain (as a point light's), the render kernel learns one more lookup.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

Optics = tuple[np.ndarray, np.ndarray, np.ndarray]     # sigma_t, sigma_s, g at a domain's cells


@dataclass
class HandOver:
    """The handed-over light of a domain on a rectilinear grid, ready for the diffusion stage.

    grid: domains.DirectionalDomain; Q0, Q1: float32 (grid shape), power and first moment along
    the grid's first axis [W]; optics: sigma_t, sigma_s, g on the grid; factor: grid cells per
    diffusion cell along each axis; faces: the budget fields that the diffusion grid's faces
    (toward the light, far, lateral) leak into; lost: power [W] the grid could not take.
    """

    grid: object
    Q0: np.ndarray
    Q1: np.ndarray
    optics: Optics
    factor: int = 1
    faces: tuple[str, str, str] = ("reflected", "transmitted", "side")
    lost: float = 0.0


class LightDomain(Protocol):
    """A light's propagation domain (domains.DirectionalDomain for a sun, lights.point's
    SphericalDomain for a point light)."""

    shape: tuple[int, int, int]

    @property
    def cell_size(self) -> float: ...

    def resample(self, medium, channel: int) -> Optics:
        """sigma_t, sigma_s, g (float32, the domain's shape) of colour ``channel``."""

    def cells_read(self, medium, seen: np.ndarray) -> np.ndarray | None:
        """bool (the domain's shape): the cells whose fields are mapped onto the ``seen``
        voxels of ``medium`` (pipeline.voxels_seen); None where the domain's walk does not use
        it."""

    def walk(self, optics: Optics, method, progress=None, read: np.ndarray | None = None):
        """Walk unit power (irradiance or intensity) from the light: a results.WalkResult, with
        ``direct`` (the unscattered part) and, when method.isotropic is "diffusion", ``handed``.
        ``read``: :meth:`cells_read`, or None (every cell's fields)."""

    def direct_fluence(self, sigma_t: np.ndarray) -> np.ndarray | None:
        """The light's unscattered fluence per unit power at the cells (float32, the domain's
        shape) through extinction ``sigma_t``; None for a light without one."""

    def hand_over(self, walk, optics: Optics, medium, method, channel: int) -> HandOver:
        """The walk's handed-over light on a rectilinear grid for the diffusion stage."""

    def world_fields(self, walk, medium, needed: np.ndarray, outs: tuple, also: tuple = ()) -> None:
        """Write phi, phi a and the direct part on the medium's world grid into ``outs`` (three
        float32 (nx, ny, nz) arrays, zeroed) where ``needed``; a light whose fields the renderer
        reads in its own domain writes nothing. ``also``: (field, out) pairs of more fields on
        the domain's own cells (its diffusion stage's, where that runs on them), written in
        the same pass."""


class Light:
    """Base class of the lights. Subclasses are dataclasses with ``source`` (for messages: the
    scene file and the light's table, ``"scene.toml: lights[0]"``) and ``from_environment``
    (one of the directional lights an environment map was split into)."""

    #: the TOML ``type`` that selects the class, and the keys its table may hold
    type: ClassVar[str]
    keys: ClassVar[frozenset]
    #: whether the renderer reads the walk's fields in the light's own domain (per sample),
    #: instead of on the world grid
    fields_in_domain: ClassVar[bool] = False
    #: the field holding its RGB power (irradiance, intensity)
    power_field: ClassVar[str]
    from_environment: bool = False
    source: str = "<light>"

    @property
    def unscattered(self) -> bool:
        """Whether the walk keeps the light's unscattered part apart (its ``direct`` field: a
        collimated sun, a point light), so that the renderer can scatter it once itself."""
        return True

    @classmethod
    def from_table(cls, table: dict, name: str, src: str) -> "Light":
        """The light of a TOML table (already checked for unknown keys)."""
        raise NotImplementedError

    @property
    def power(self) -> np.ndarray:
        """float64 (3,): what the renderer scales the per-unit fields by."""
        return getattr(self, self.power_field)

    def field(self, name: str) -> tuple[str, str]:
        """(field name, source) for check.py's messages: ``lights[0].position``, ``scene.toml``."""
        src, _, table = self.source.rpartition(": ")
        return (f"{table}.{name}", src) if src else (f"light.{name}", self.source)

    def key(self) -> tuple:
        """What its per-unit-power solution depends on (not its power)."""
        raise NotImplementedError

    def check(self, medium) -> None:
        """Refuse, with a PopvolError, a light this medium cannot be solved for (default: none)."""

    def domain(self, medium, method) -> LightDomain:
        raise NotImplementedError

    def table(self) -> dict:
        """Its TOML table (plain floats), as :meth:`from_table` reads it."""
        raise NotImplementedError

    def scaled(self, factor: float) -> "Light":
        """The same light with its power times ``factor``."""
        return dataclasses.replace(self, **{self.power_field: self.power * factor})

    def mitsuba(self) -> dict:
        """Its Mitsuba 3 emitter dict (the reference renderer's plugin parameters)."""
        raise NotImplementedError

    def digest(self) -> bytes:
        """Bytes that identify it in a reference image's scene digest."""
        raise NotImplementedError

    # where the renderer looks it up: a direction (suns) or a position (point lights)
    render_direction = np.zeros(3)
    render_position = np.zeros(3)
