"""What solving produces: a domain's walk, its energy budget, and the scene's fields for the
renderer (docs/METHOD.md, "Energy balance" and "Rendering")."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .kernels.render import MAX_DIFFUSE_ANISOTROPY

#: Budget fields, in the order the kernels' tallies use for the first three.
BUDGET_FIELDS = ("injected", "reflected", "transmitted", "side", "diffusion_leak", "absorbed", "in_flight")


@dataclass
class Budget:
    """Energy budget of one domain [W, per unit irradiance or intensity] (docs/METHOD.md,
    "Energy balance"): injected = escaped + absorbed + in flight, up to float rounding."""

    injected: float = 0.0
    reflected: float = 0.0     # left through the face toward the light (a cone's inner sphere)
    transmitted: float = 0.0   # left through the far face (the outer sphere)
    side: float = 0.0          # left through the lateral faces
    absorbed: float = 0.0
    in_flight: float = 0.0     # still pending when the walk stopped
    diffusion_leak: float = 0.0  # handed-over light the diffusion grid could not hold or keep

    @property
    def escaped(self) -> float:
        return self.reflected + self.transmitted + self.side + self.diffusion_leak

    @property
    def balance_error(self) -> float:
        """(injected - escaped - absorbed - in flight) / injected: 0 up to float rounding."""
        return (self.injected - self.escaped - self.absorbed - self.in_flight) / max(self.injected, 1e-300)

    def add_diffusion(self, diffusion, faces=("reflected", "transmitted", "side"), lost: float = 0.0) -> None:
        """Book the diffusion stage: what it absorbed, what left its grid's faces (toward the
        light, far, lateral: added to the budget fields named by ``faces``), and what leaked
        into empty cells or was ``lost`` before it (diffusion_leak)."""
        self.absorbed += diffusion.absorbed
        for name, watts in zip(faces, diffusion.leaked[:3]):
            setattr(self, name, getattr(self, name) + watts)
        self.diffusion_leak += diffusion.leaked[3] + lost

    def as_dict(self) -> dict:
        d = {k: float(getattr(self, k)) for k in BUDGET_FIELDS}
        d["escaped"] = self.escaped
        d["balance_error"] = self.balance_error
        return d


@dataclass
class WalkResult:
    """A domain's walk: accumulated fields and how the solver got there.

    phi, phia: float32 (domain shape): fluence [W/m^2 per unit irradiance or intensity] and
    fluence times the lobe's anisotropy (A = phia / phi). direct: float32 (domain shape), the
    part of phi that is unscattered light (None for lights without one). handed: float32
    (2, domain shape), power and first moment handed over to the diffusion stage [W] (None
    without it). diffusion: the diffusion.DiffusionResult once the pipeline has solved it.
    flux: float32 (3, domain shape), the fluence's first moment vector in the domain's frame
    (the six-ordinate walk only; phia is then its component along the axis d). A six-ordinate
    walk given the cells read leaves phi, phia and flux 0 in the empty cells it crossed
    without visits (walk.skipped_cells); ``direct`` is the unscattered light everywhere.
    direct_a0: the mean cosine of the unscattered light's lobe about the light's direction: 1
    for a collimated sun; an environment region's a0 where its ordinates' walk keeps its
    unscattered lobe in ``direct`` (Beer-Lambert along the region's direction, a part of phi;
    docs/METHOD.md Eq. 26a).
    direct_transport: float32 (domain shape), where the walk solved a capped medium
    (medium.transport_medium) and ``direct`` was swapped for the unscattered light through the
    true density (walk.replace_direct): the walk's own, through the capped density, which the
    gathered last bounce scatters (docs/METHOD.md Eq. 25g); None otherwise.
    pending, tail: where the eighteen-ordinate walk stopped at ``method.tail`` of its light in
    flight, the packets it then held (walk.block_packets) and their walk on blocks of its cells
    (walk.walk_tail; its phi and flux on the blocks, a part of the scattered light); None where
    it walked to the tolerance.
    scattered: a point light's light that scattered at least once, walked by the ordinates on
    a box of the medium (lights.point, docs/METHOD.md "A point light's ordinates"): that walk's
    own result on the domain's ``grid`` (its ``direct`` None), while phi, phia and direct here
    hold the unscattered light alone; None otherwise.
    """

    phi: np.ndarray
    phia: np.ndarray
    budget: Budget
    iterations: int            # Jacobi iterations or sweeps
    cell_updates: int          # cells visited by the solver (for throughput figures)
    residual: float            # in-flight energy / injected energy when it stopped
    converged: bool
    seconds: float = 0.0
    solver: str = "sweep"
    direct: np.ndarray | None = None
    direct_a0: float = 1.0
    handed: np.ndarray | None = None
    diffusion: object = None
    seconds_diffusion: float = 0.0
    flux: np.ndarray | None = None
    direct_transport: np.ndarray | None = None
    scattered: "WalkResult | None" = None
    cells_sent: int = 0        # the sweeps' cells that sent a packet, summed over the sweeps (the work
                               # they did; the six-ordinate sweeps count packets, up to six a cell;
                               # a Jacobi wavefront does not count them)
    pending: tuple | None = None   # packets taken out when it stopped for its tail (walk.walk_tail)
    tail: "WalkResult | None" = None   # its tail's walk on blocks of its cells (walk.walk_the_tail)


@dataclass
class DomainSolution:
    """One light (and colour channel) solved in its domain."""

    light: object              # a lights.Light
    domain: object             # its LightDomain
    result: WalkResult
    seconds_resample: float
    channel: int = 0           # colour channel of a chromatic medium (0 for grey media)
    light_index: int = 0       # which of the scene's lights
    reused: bool = False       # copied from an earlier solution (pipeline.solve's ``reuse``)
    diffusion_grid: object = None   # domains.DirectionalDomain of the diffusion stage
    warm: bool = False         # its diffusion solve started from an earlier frame's (pipeline.solve's ``warm``)
    warm_note: str = ""        # why it was not warm-started, or how (empty without ``warm``)

    @property
    def direct(self) -> np.ndarray | None:
        return self.result.direct

    def stats(self) -> dict:
        r = self.result
        return {"light": self.light_index, "channel": self.channel, "reused": self.reused,
                "type": self.light.type, "shape": list(self.domain.shape),
                "cell_size": self.domain.cell_size, "solver": r.solver, "iterations": r.iterations,
                "residual": r.residual, "converged": r.converged, "cell_updates": r.cell_updates,
                "cells_sent": r.cells_sent,
                "tail_sweeps": r.tail.iterations if r.tail else 0,
                "tail_cells_sent": r.tail.cells_sent if r.tail else 0,
                "seconds_resample": self.seconds_resample, "seconds_propagate": r.seconds,
                "seconds_diffusion": r.seconds_diffusion,
                "diffusion_iterations": r.diffusion.iterations if r.diffusion else 0,
                "diffusion_residual": r.diffusion.residual if r.diffusion else 0.0,
                "warm": self.warm, "warm_note": self.warm_note,
                "budget_per_unit_irradiance": r.budget.as_dict()}


@dataclass
class PointFields:
    """The walk's fields of the lights whose fields stay in their own spherical domains, for
    the renderer, which looks them up per sample: r^2 phi, r^2 phia and r^2 phi_dir (smooth
    where phi has the light's 1/r^2 spike; the renderer divides by each sample's own r^2).

    fields: float32 (3, total): the three fields of every domain (light, channel), each block
        C-ordered (n_r, n_theta, n_phi);
    offset: int64 (n_lights, n_channels): start of each block (-1 for other lights);
    shape: int64 (n_lights, 3); params: float64 (n_lights, 6) (r0, dr, theta0, dtheta, phi0,
    dphi); frame: float64 (n_lights, 3, 3); full: bool (n_lights,) (see lights.point).
    """

    fields: np.ndarray
    offset: np.ndarray
    shape: np.ndarray
    params: np.ndarray
    frame: np.ndarray
    full: np.ndarray

    @staticmethod
    def empty(n_lights: int, n_channels: int) -> "PointFields":
        return PointFields(np.zeros((3, 1), np.float32), -np.ones((n_lights, n_channels), np.int64),
                           np.ones((n_lights, 3), np.int64), np.ones((n_lights, 6)),
                           np.tile(np.eye(3), (n_lights, 1, 1)), np.zeros(n_lights, np.bool_))


def _empty(*shape):
    return np.zeros(shape, np.float32)


@dataclass
class Solution:
    """Everything rendering needs: per-light fields, per unit irradiance (suns) or intensity
    (point lights); the renderer multiplies by each light's RGB power.

    phi, phia, direct: float32 (n_lights, n_channels, nx, ny, nz) on the medium's world grid
    (grey media: n_channels = 1): the walk's fluence, fluence times anisotropy along the
    light's direction, and its unscattered part. Zero for lights whose fields stay in their
    own domain (``points``; is_point). phid: float32 (n_lights, n_channels, nx, ny, nz), the
    diffuse light's fluence, and flux: float32 (n_lights, n_channels, 3, nx, ny, nz), its
    world-space flux vector J (arrays with n_lights = 0 without the diffusion stage or the
    six-ordinate walk, whose scattered light they hold: docs/METHOD.md, "Six ordinates").
    All fields are 0 at voxels the renderer never reads (pipeline.voxels_seen). An
    environment region walked by the ordinates keeps its unscattered lobe in ``direct`` (a part
    of its phid, its phi and phia 0; ``lobe_a0``), which the gathered last bounce alone reads.
    """

    medium: object
    domains: list[DomainSolution]
    phi: np.ndarray
    phia: np.ndarray
    direct: np.ndarray
    directions: np.ndarray     # float64 (n_lights, 3): direction each sun's light travels
    positions: np.ndarray      # float64 (n_lights, 3): each point light's position
    is_point: np.ndarray       # bool (n_lights,): fields in ``points``, not on the world grid
    irradiance: np.ndarray     # float64 (n_lights, 3): each light's power (irradiance, intensity)
    points: PointFields
    phid: np.ndarray = field(default_factory=lambda: _empty(0, 1, 1, 1, 1))
    flux: np.ndarray = field(default_factory=lambda: _empty(0, 1, 3, 1, 1, 1))
    seconds: dict = field(default_factory=dict)   # per stage, summed over the domains (which
    #                          overlap where solved side by side: pipeline.side_by_side)
    key: tuple = ()            # what it was solved for (pipeline.solve's reuse)
    lobe_cap: np.ndarray | None = None   # float64 (n_lights,): the largest anisotropy of each
    #                          light's phid lobe (None: MAX_DIFFUSE_ANISOTROPY for every light)
    single: bool = False       # the unscattered light alone (single_scattering()): the renderer
    #                          gathers no further scattering from it
    unscattered: np.ndarray | None = None   # bool (n_lights,): the light's unscattered part is
    #                          in ``direct`` (Light.unscattered; None: every light's)
    lobe_a0: np.ndarray | None = None   # float64 (n_lights,): an environment region's a0 where
    #                          ``direct`` holds its unscattered lobe, a part of phid (Eq. 26a); else 0
    cache: dict = field(default_factory=dict, repr=False, compare=False)   # what the renderer
    #                          makes of these fields for any camera, kept for the next frame:
    #                          name -> (key, what the key's ids belong to, value), e.g.
    #                          renderer.gather_state's; relit() and single_scattering() share it

    def __post_init__(self):
        if self.lobe_cap is None:
            self.lobe_cap = np.full(len(self.is_point), MAX_DIFFUSE_ANISOTROPY)
        if self.unscattered is None:
            self.unscattered = np.ones(len(self.is_point), np.bool_)

    def relit(self, lights) -> "Solution":
        """The same fields under ``lights`` of other powers (fields are per unit power)."""
        power = np.array([l.power for l in lights], np.float64).reshape(-1, 3)
        return dataclasses.replace(self, irradiance=power)

    def single_scattering(self) -> "Solution":
        """The same scene lit by its unscattered light alone: each light's fluence is its
        direct part (phi = phia = phi_dir, a lobe of anisotropy 1 along the light's direction,
        which the renderer lights with f_hg(mu; g): docs/METHOD.md Eq. 23), with no diffuse
        light. Rendered, it is the light that reaches the camera after exactly one scattering
        event, what a path tracer's paths of that length give (Mitsuba volpath ``max_depth =
        2``), whatever ``method.gather`` says. Environment lights (a0 < 1) have no direct part,
        so they give nothing here."""
        fields = np.repeat(self.points.fields[2:3], 3, axis=0)     # rows phi, phia := phi_dir
        direct = self.direct
        if self.lobe_a0 is not None and np.any(self.lobe_a0 > 0):
            # an environment region's unscattered lobe is not a delta lobe along its direction:
            # its rows 0 (np.zeros: pages Linux maps when first touched, not written here), the
            # others copied
            direct = np.zeros(self.direct.shape, self.direct.dtype)
            for l in np.flatnonzero(self.lobe_a0 <= 0):
                direct[l] = self.direct[l]
        return dataclasses.replace(self, phi=direct, phia=direct, direct=direct,
                                   phid=_empty(0, *self.phid.shape[1:]), flux=_empty(0, *self.flux.shape[1:]),
                                   points=dataclasses.replace(self.points, fields=fields), single=True, lobe_a0=None)

    @property
    def nbytes(self) -> int:
        """Bytes of every array the solution holds for rendering, what the renderer keeps with
        it (``cache``) included."""
        kept = sum(_array_bytes(value) for _key, _held, value in self.cache.values())
        return sum(a.nbytes for a in (self.phi, self.phia, self.direct, self.phid, self.flux,
                                      self.points.fields)) + kept

    def stats(self) -> dict:
        """Seconds per stage, the grid the fields are on (the medium's, or at method.voxel_depth
        its finer voxels) and each domain's figures."""
        return {"seconds": dict(self.seconds), "grid": list(self.medium.shape),
                "domains": [ds.stats() for ds in self.domains]}


def _array_bytes(x) -> int:
    """Bytes of the NumPy arrays in ``x``, a value of nested tuples, lists and dicts."""
    if isinstance(x, np.ndarray):
        return x.nbytes
    if isinstance(x, dict):
        return sum(_array_bytes(v) for v in x.values())
    if isinstance(x, (tuple, list)):
        return sum(_array_bytes(v) for v in x)
    return 0
