"""Principal-Ordinate Propagation of each light through the medium (METHOD.md steps 2-5).

Data flow: medium -> light-aligned domain (resampled sigma_t, sigma_s, g) -> injection at the
face toward the light -> propagation (Jacobi wavefront or Gauss-Seidel sweeps) -> accumulated
fluence phi and phi*A per domain cell -> resampled onto the medium's world grid ("fields") for
rendering.

Grey media are linear in the light's energy (the anisotropy merge is energy-weighted, so it is
independent of scale): each domain is solved once for unit irradiance and scaled by the light's
RGB irradiance when rendering.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from . import hg
from .diffusion import solve_diffusion
from .domains import DirectionalDomain, SphericalDomain, check_memory, directional_domain
from .kernels import propagation as K
from .kernels.sampling import domain_to_world, resample
from .lights import DirectionalLight, PointLight
from .medium import Medium
from .scene import Method, Scene

SPLIT_TABLE_SIZE = 4097
SOUTHWELL_FRACTION = 2.0      # see propagate(): cells send above twice the mean pending energy


@functools.lru_cache(maxsize=4)
def split_table(n: int = SPLIT_TABLE_SIZE) -> np.ndarray:
    """float64 (n, 8): front/side/back shares and their conditional mean cosines for a lobe
    HG_a, sampled at a = linspace(-1, 1, n) (supplement Eq. 2, 4, 7); columns 6, 7 are padding
    so that one row is 64 bytes (the kernels read two neighbouring rows per lookup)."""
    a = np.linspace(-1.0, 1.0, n)
    table = np.zeros((n, 8))
    table[:, 0], table[:, 1], table[:, 2] = hg.split_fractions(a)
    table[:, 3], table[:, 4], table[:, 5] = hg.conditional_mean_cosines(a)
    return table


@functools.lru_cache(maxsize=4)
def split_table32(n: int = SPLIT_TABLE_SIZE) -> np.ndarray:
    """:func:`split_table` in float32, what the kernels read (see kernels.propagation.split)."""
    return split_table(n).astype(np.float32)


def handover_factor(sigma_t, sigma_s, g, s) -> np.ndarray:
    """float32: per cell, the factor f = 1 - exp(-sigma_tr s) of the hand-over threshold
    |a| < method.handover_scale * f (sigma_tr = sigma_a + sigma_s (1 - g), s the cell's step length,
    broadcastable): the share of a lobe's first moment that the medium itself removes over one
    cell. Light hands over once its anisotropy is below what one cell's scattering resolves, so
    the criterion follows the medium's transport mean free path, not the cell count (a fixed
    threshold handed light over sooner per unit length on finer grids: images darkened 5-13 %
    from 64 to 128 cells). 0 outside the diffusion region (sigma_s = 0 or sigma_t = 0)."""
    sigma_a = np.maximum(sigma_t - sigma_s, 0.0)
    sigma_tr = sigma_a + sigma_s * (1.0 - g)
    f = -np.expm1(-sigma_tr * s)
    return np.where((sigma_s > 0) & (sigma_t > 0), f, 0.0).astype(np.float32)


def direct_fluence(sigma_t: np.ndarray, h: float) -> np.ndarray:
    """float32 (n_d, n_u, n_v): fluence of a sun's unscattered light at the cell centres of its
    domain, per unit irradiance: exp(-tau), tau = sigma_t integrated from the face k = 0 to the
    centre (Beer-Lambert with the cells' sigma_t piecewise constant, the half steps of the
    walk's transmittance). The walk carries this light too (in its fields, with a = 1 until the
    first decay); the renderer lights it with its own lobe (see kernels/render.py)."""
    tau_half = np.asarray(sigma_t, np.float64) * (0.5 * h)
    tau = 2.0 * np.cumsum(tau_half, axis=0) - tau_half
    return np.exp(-tau).astype(np.float32)


def medium_factors(sigma_t: np.ndarray, sigma_s: np.ndarray, g: np.ndarray, h: float,
                   decay: str) -> tuple[np.ndarray, np.ndarray]:
    """Half-step transmittance Th and anisotropy decay Dh per cell, float32 (same shape).

    Th = exp(-sigma_a h / 2)  (only absorption removes energy; scattering widens the lobe).
    Dh = g^(sigma_s h / 2)    (decay "paper", supplement Eq. 12; needs g >= 0), or
         exp(-sigma_s h (1 - g) / 2)  (decay "poisson": E[g^n] for n ~ Poisson(sigma_s h)).
    """
    sigma_a = np.maximum(sigma_t - sigma_s, 0.0)
    Th = np.exp(-0.5 * h * sigma_a)
    x = 0.5 * h * sigma_s
    if decay == "paper":
        with np.errstate(divide="ignore"):
            Dh = np.where(x > 0, np.power(np.maximum(g, 0.0), x), 1.0)
    else:
        Dh = np.exp(-x * (1.0 - g))
    return Th.astype(np.float32), Dh.astype(np.float32)


@dataclass
class Budget:
    """Energy budget of one domain [W, for unit irradiance]; see supplement Sec. 1.2."""

    injected: float = 0.0
    reflected: float = 0.0     # left through the face toward the light
    transmitted: float = 0.0   # left through the far face
    side: float = 0.0          # left through the 4 lateral faces
    absorbed: float = 0.0
    in_flight: float = 0.0     # still pending when the solver stopped
    diffusion_leak: float = 0.0  # diffuse light that left the diffusion region into empty cells

    @property
    def escaped(self) -> float:
        return self.reflected + self.transmitted + self.side + self.diffusion_leak

    @property
    def balance_error(self) -> float:
        """(injected - escaped - absorbed - in flight) / injected: 0 up to float rounding."""
        return (self.injected - self.escaped - self.absorbed - self.in_flight) / max(self.injected, 1e-300)

    def as_dict(self) -> dict:
        d = {k: float(getattr(self, k)) for k in ("injected", "reflected", "transmitted", "side",
                                                   "diffusion_leak", "absorbed", "in_flight")}
        d["escaped"] = self.escaped
        d["balance_error"] = self.balance_error
        return d


@dataclass
class PropagationResult:
    """Accumulated fields of one domain and how the solver got there."""

    phi: np.ndarray            # float32 domain shape: fluence [W/m^2]
    phia: np.ndarray           # float32: sum of fluence * anisotropy; A = phia / phi
    budget: Budget
    iterations: int            # Jacobi iterations or sweeps
    cell_updates: int          # cells visited by the solver (for throughput figures)
    residual: float            # in-flight energy / injected energy when it stopped
    converged: bool
    seconds: float = 0.0
    diffusion: object = None   # diffusion.DiffusionResult when the isotropic stage is "diffusion"
    seconds_diffusion: float = 0.0


def default_max_iterations(shape, solver: str) -> int:
    if solver == "jacobi":
        return 40 * int(sum(shape))
    return 400


def sweep_until_converged(one_sweep, in_flight: float, target: float, cap: int, n_cells: int,
                          injected: float, progress=None) -> tuple[float, int]:
    """Run thresholded Gauss-Seidel sweeps until the power in flight is <= target or ``cap``
    sweeps have run; ``one_sweep(it, w_min)`` sweeps once and returns (power still in flight,
    number of cells that sent). Returns (in flight, sweeps).

    Southwell-style: only cells holding more than twice the mean pending energy (over all
    cells) send; the others wait for more to arrive. On the WDAS cloud this skips most of the
    faint diffuse light in empty space: 30-40 % faster than sending every cell, images equal
    to 0.5 %. Near the tolerance the fraction drops to 1/2 (the fullest cell always qualifies:
    max >= mean), and should no cell qualify, the next sweep sends them all.
    """
    fraction = SOUTHWELL_FRACTION
    it = 0
    while in_flight > target and it < cap:
        if in_flight < 10.0 * target:
            fraction = min(fraction, 0.5)
        in_flight, sent = one_sweep(it, fraction * in_flight / n_cells)
        fraction = fraction if sent > 0 else 0.0
        it += 1
        if progress is not None:
            progress(it, in_flight / injected)
    return in_flight, it


def propagate(Th: np.ndarray, Dh: np.ndarray, injection: np.ndarray, a0: float, h: float,
              rule: str = "moment", solver: str = "sweep", tolerance: float = 1e-3,
              max_iterations: int = 0, periodic: bool = False, progress=None,
              isotropic: str = "walk", handover: float = 2.0, medium=None,
              diffusion_factor: int = 1) -> PropagationResult:
    """Propagate light injected into slice k = 0 of a domain until it has (almost) all left.

    Args:
        Th, Dh: float32 (n_d, n_u, n_v) half-step factors from :func:`medium_factors`.
        injection: (n_u, n_v) power [W] entering each cell of slice 0 (E * h^2 for a sun).
            The light travels half a cell to the first centre, so it is attenuated by Th[0].
        a0: anisotropy of the injected lobe (1 = collimated).
        h: cell size; fluence accumulates W / h^2 per visit.
        rule: "moment" or "paper"; solver: "sweep" or "jacobi".
        tolerance: stop when in-flight energy < tolerance * injected; max_iterations: cap
            (0 = automatic).
        periodic: wrap the lateral faces (an infinite slab); used by the slab tests.
        progress: optional callable(iteration, residual).
        isotropic: "walk" (diffuse light keeps walking, the papers' POP) or "diffusion" (a packet
            whose |a| < ``handover`` * handover_factor (of its cell) leaves the walk for a diffusion solve,
            see diffusion.py); ``medium`` = (sigma_t, sigma_s, g) of the domain is then needed,
            and the diffusion grid has blocks of ``diffusion_factor``^3 domain cells.
    """
    Th = np.ascontiguousarray(Th, np.float32)
    Dh = np.ascontiguousarray(Dh, np.float32)
    shape = Th.shape
    moment = rule == "moment"
    table = split_table32()
    inv_area = np.float32(1.0 / (h * h))
    cap = max_iterations or default_max_iterations(shape, solver)

    W = np.zeros(shape, np.float32)
    phi = np.zeros(shape, np.float32)
    phia = np.zeros(shape, np.float32)
    budget = Budget(injected=float(np.sum(injection, dtype=np.float64)))
    if isotropic == "diffusion":
        if medium is None:
            raise ValueError("isotropic = 'diffusion' needs medium = (sigma_t, sigma_s, g)")
        if periodic:
            raise ValueError("the diffusion stage has no periodic boundaries")
        sigma_t, sigma_s, g = medium
        diffusive = handover_factor(sigma_t, sigma_s, g, h)
        Q = np.zeros((2,) + shape, np.float32)
        eps = float(handover)
    else:
        diffusive = np.zeros((1, 1, 1), np.float32)
        Q = np.zeros((2, 1, 1, 1), np.float32)
        eps = -1.0
    tally = np.zeros(4)
    target = tolerance * budget.injected
    t0 = time.perf_counter()
    it = 0
    if solver == "jacobi":
        # the wave holds packets at cell centres: the injected light has crossed half a cell
        W[0] = injection * Th[0]
        Wa = W * np.float32(a0)
        Wa[0] *= Dh[0]
        budget.absorbed = float(np.sum(injection * (1.0 - Th[0]), dtype=np.float64))
        in_flight = float(np.sum(W, dtype=np.float64))
        parts = np.empty((6,) + shape, np.float32)
        while in_flight > target and it < cap:
            K.jacobi_send(W, Wa, Th, Dh, table, moment, periodic, inv_area, phi, phia, parts, tally,
                          eps, diffusive, Q)
            in_flight = K.jacobi_gather(parts, Th, Dh, periodic, W, Wa, tally)
            it += 1
            if progress is not None and it % 16 == 0:
                progress(it, in_flight / budget.injected)
    else:
        # pending packets have arrived at the face of their cell; the cell applies its half step
        W[0] = injection
        Wa = W * np.float32(a0)
        in_flight = budget.injected
        bands = K.band_edges(shape[1])
        halo = np.zeros((len(bands) - 1, 2, 2, shape[0], shape[2]), np.float32)
        tally_b = np.zeros((len(bands) - 1, 5))
        def one_sweep(it, w_min):
            # alternate +d / -d every sweep and the lateral order every second sweep
            with numba.parallel_chunksize(1):     # bands to threads one at a time (see K)
                left = K.sweep(W, Wa, Th, Dh, table, moment, periodic, it % 2 == 0, it % 4 >= 2,
                               w_min, inv_area, phi, phia, bands, halo, tally_b, tally, eps, diffusive, Q)
            return left, tally_b[:, 4].sum()
        in_flight, it = sweep_until_converged(one_sweep, in_flight, target, cap, Th.size,
                                              budget.injected, progress)
    seconds = time.perf_counter() - t0
    budget.reflected, budget.transmitted, budget.side = (float(x) for x in tally[:3])
    budget.absorbed += float(tally[K.ABSORBED])
    budget.in_flight = in_flight
    residual = in_flight / max(budget.injected, 1e-300)
    result = PropagationResult(phi, phia, budget, it, it * int(np.prod(shape)), residual,
                               in_flight <= target, seconds)
    if isotropic == "diffusion":
        t1 = time.perf_counter()
        d = solve_diffusion(Q[0], Q[1], sigma_t, sigma_s, g, h, rtol=0.1 * tolerance,
                            factor=diffusion_factor)
        budget.absorbed += d.absorbed
        budget.reflected += d.leaked[0]
        budget.transmitted += d.leaked[1]
        budget.side += d.leaked[2]
        budget.diffusion_leak = d.leaked[3]
        result.diffusion = d
        result.seconds_diffusion = time.perf_counter() - t1
    return result


# ---------------------------------------------------------------------------------------------
# Whole scenes
# ---------------------------------------------------------------------------------------------

@dataclass
class DomainSolution:
    light: DirectionalLight | PointLight
    domain: DirectionalDomain | SphericalDomain
    result: PropagationResult
    seconds_resample: float
    channel: int = 0           # colour channel of a chromatic medium (0 for grey media)
    light_index: int = 0       # which of the scene's lights
    reused: bool = False       # copied from an earlier solution (solve's ``reuse``)
    diffusion_domain: DirectionalDomain | None = None   # grid of the diffusion stage if not ``domain``
    direct: np.ndarray | None = None   # a sun's unscattered fluence on ``domain`` (direct_fluence)


@dataclass
class Solution:
    """Everything rendering needs: per-light fields on the medium's world grid.

    phi, phia: float32 (n_lights, n_channels, nx, ny, nz), per unit irradiance (grey media:
    n_channels = 1; the renderer multiplies by each light's RGB irradiance): the walk's lobe,
    along each light's direction. Zero for a point light, whose walk fields stay in its
    spherical domain (``points``, per unit intensity, times r^2; see spherical.py).
    phid: float32 (n_lights, n_channels, nx, ny, nz), fluence of the diffuse light, and
    flux: float32 (n_lights, n_channels, 3, nx, ny, nz), its world-space flux vector J
    (isotropic stage "diffusion"; arrays with n_lights = 0 otherwise).
    direct: float32 like phi: the part of phi that is a sun's unscattered light (a collimated
    light, a0 = 1; 0 for environment lights and point lights), per unit irradiance.
    All fields are 0 at voxels the renderer never reads (:func:`voxels_seen`).
    """

    medium: Medium
    domains: list[DomainSolution]
    phi: np.ndarray
    phia: np.ndarray
    directions: np.ndarray     # float64 (n_lights, 3), direction each light travels (suns)
    irradiance: np.ndarray     # float64 (n_lights, 3): irradiance (suns), intensity (points)
    seconds: dict = field(default_factory=dict)
    phid: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 1, 1, 1), np.float32))
    flux: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 3, 1, 1, 1), np.float32))
    key: tuple = ()            # medium_key and method_key it was solved for (see solve's reuse)
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (n_lights, 3)
    is_point: np.ndarray = field(default_factory=lambda: np.zeros(0, np.bool_))  # (n_lights,)
    points: object = None      # spherical.PointFields: point lights' walk fields, in their domains
    direct: np.ndarray = field(default_factory=lambda: np.zeros((0, 1, 1, 1, 1), np.float32))

    def stats(self) -> dict:
        out = {"seconds": dict(self.seconds), "domains": []}
        for ds in self.domains:
            r = ds.result
            out["domains"].append({
                "light": ds.light_index, "channel": ds.channel, "reused": ds.reused,
                "type": "point" if isinstance(ds.light, PointLight) else "directional",
                "shape": list(ds.domain.shape),
                "cell_size": ds.domain.dr if isinstance(ds.domain, SphericalDomain) else ds.domain.h, "iterations": r.iterations, "residual": r.residual,
                "converged": r.converged, "cell_updates": r.cell_updates,
                "seconds_resample": ds.seconds_resample, "seconds_propagate": r.seconds,
                "seconds_diffusion": r.seconds_diffusion,
                "diffusion_iterations": r.diffusion.iterations if r.diffusion else 0,
                "budget_per_unit_irradiance": r.budget.as_dict()})
        return out


def resample_medium(medium: Medium, domain: DirectionalDomain, channel: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sigma_t, sigma_s, g of colour ``channel`` at the domain's cell centres, float32
    (n_d, n_u, n_v) each. Per-voxel albedo and g are resampled like the density (clamped to
    the edge outside the grid, where the density is zero anyway)."""
    def grid(values, clamp):
        out = np.empty(domain.shape, np.float32)
        resample(values, 1.0 / medium.voxel_size, medium.origin, domain.frame, domain.origin,
                 domain.h, domain.shape, clamp, out)
        return out
    return optics(medium, grid, domain.shape, channel)


def optics(medium: Medium, grid, shape, channel: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sigma_t, sigma_s, g (float32 ``shape``) of colour ``channel`` at a domain's cells, where
    ``grid(values, clamp)`` samples a world voxel grid at those cells (0 outside the grid, or
    clamped to its edge if ``clamp``: per-voxel albedo and g, where the density is 0 anyway)."""
    sigma_t = grid(medium.density, False) * np.float32(medium.scale[channel])
    if medium.albedo_per_voxel:
        sigma_s = sigma_t * grid(medium.albedo, True)
    else:
        sigma_s = sigma_t * np.float32(medium.albedo[channel])
    g = grid(medium.g, True) if medium.g_per_voxel else np.full(shape, medium.g, np.float32)
    return sigma_t, sigma_s, g


def diffusion_factor(shape, method: Method) -> int:
    """Domain cells per diffusion cell along each axis: the diffusion grid has about
    method.diffusion_resolution cells along the domain's longest side (0: the domain's own)."""
    if not method.diffusion_resolution:
        return 1
    return max(1, round(max(shape) / method.diffusion_resolution))


def check_decay(medium: Medium, method: Method) -> None:
    """decay = 'paper' raises g to a power: it needs g >= 0 everywhere."""
    if method.decay == "paper" and medium.g_min < 0:
        from .errors import PopvolError
        raise PopvolError(f"{medium.source}: method.decay = 'paper' (g^(sigma_s s), supplement "
                          f"Eq. 12) needs g >= 0, got g = {medium.g_min:g}; use decay = 'poisson'")


def solve_light(medium: Medium, light: DirectionalLight, method: Method, progress=None,
                channel: int = 0) -> DomainSolution:
    """Build the light's domain, resample the medium (colour ``channel``) into it and propagate
    unit irradiance."""
    check_decay(medium, method)
    t0 = time.perf_counter()
    resolution = method.resolution
    if light.from_environment and method.environment_resolution:
        resolution = method.environment_resolution
    dom = directional_domain(medium, light.direction, resolution)
    sigma_t, sigma_s, g = resample_medium(medium, dom, channel)
    Th, Dh = medium_factors(sigma_t, sigma_s, g, dom.h, method.decay)
    diffusion = method.isotropic == "diffusion"
    medium_arrays = (sigma_t, sigma_s, g) if diffusion else None
    direct = direct_fluence(sigma_t, dom.h) if light.a0 == 1.0 else None
    del sigma_t, sigma_s, g
    t1 = time.perf_counter()
    injection = np.full(dom.shape[1:], dom.h * dom.h, np.float32)   # unit irradiance * area
    res = propagate(Th, Dh, injection, light.a0, dom.h, method.rule, method.solver,
                    method.tolerance, method.max_iterations, progress=progress,
                    isotropic=method.isotropic, handover=method.handover_scale, medium=medium_arrays,
                    diffusion_factor=diffusion_factor(dom.shape, method))
    return DomainSolution(light, dom, res, t1 - t0, channel, direct=direct)


def voxels_seen(density: np.ndarray) -> np.ndarray:
    """bool (nx, ny, nz): the voxels the renderer can read fields from. It reads them only where
    the density is > 0, by trilinear interpolation, so the voxels within one voxel (26
    neighbours) of a non-empty one; fields elsewhere are left 0."""
    m = density > 0
    for axis in range(3):                  # separable 3x3x3 dilation
        d = m.copy()
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        d[tuple(lo)] |= m[tuple(hi)]
        d[tuple(hi)] |= m[tuple(lo)]
        m = d
    return m


def medium_key(medium: Medium) -> tuple:
    """What propagation depends on in a medium: grids by identity (a Medium made from another
    with ``dataclasses.replace`` shares them), numbers by value."""
    def value(v):
        return ("grid", id(v)) if np.ndim(v) == 3 else tuple(np.atleast_1d(v).tolist())
    return (id(medium.density), medium.density.shape, tuple(medium.origin), tuple(medium.voxel_size),
            value(medium.scale), value(medium.albedo), value(medium.g))


#: Method fields that only rendering reads: changing them keeps a solution valid.
RENDER_ONLY = ("step", "spp", "exposure", "seed")


def method_key(method: Method) -> tuple:
    return tuple((k, v) for k, v in vars(method).items() if k not in RENDER_ONLY)


def light_key(light) -> tuple:
    """What a light's per-unit-irradiance domain solution depends on (not its irradiance)."""
    if isinstance(light, PointLight):
        return ("point", tuple(light.position))
    # rounded: normalising an already unit direction again may change its last bit
    return ("directional", tuple(np.round(light.direction, 12)), light.a0, light.from_environment)


def solve(scene: Scene, progress=None, reuse: Solution | None = None) -> Solution:
    """Propagate every light of ``scene`` (and every colour channel of a chromatic medium);
    returns the fields the renderer needs.

    ``reuse``: an earlier solution. Lights that it solved for the same medium and method
    (irradiance may differ: fields are per unit irradiance) are copied from it instead of
    propagated again, so moving one light of several re-propagates that light only, and
    changing a light's irradiance or the camera re-propagates nothing. Grids are compared by
    identity: a medium whose arrays were changed in place must not be solved with ``reuse``.
    """
    from .spherical import point_fields, solve_point_light
    med = scene.medium
    n = len(scene.lights)
    n_ch = med.n_channels
    check_memory(3 * n * n_ch * med.density.size * 4, f"{med.source}: medium", f"fields of {n} "
                 f"light(s) x {n_ch} channel(s) on a {'x'.join(map(str, med.shape))} grid")
    # zeros: the fields are written only where the renderer reads them (voxels_seen); calloc'd
    # pages that are never written cost nothing
    phi = np.zeros((n, n_ch) + med.shape, np.float32)
    phia = np.zeros_like(phi)
    direct = np.zeros_like(phi)
    diffusion = scene.method.isotropic == "diffusion"
    if diffusion:
        check_memory(4 * n * n_ch * med.density.size * 4, f"{med.source}: medium",
                     f"diffusion fields of {n} light(s) x {n_ch} channel(s)")
        phid = np.zeros((n, n_ch) + med.shape, np.float32)
        flux = np.zeros((n, n_ch, 3) + med.shape, np.float32)
    else:
        phid = np.zeros((0, n_ch, 1, 1, 1), np.float32)
        flux = np.zeros((0, n_ch, 3, 1, 1, 1), np.float32)
    key = (medium_key(med), method_key(scene.method))
    old = {}
    if reuse is not None and reuse.key == key:
        for ds in reuse.domains:
            old[light_key(ds.light), ds.channel] = ds
    needed = voxels_seen(med.density)
    sols = []
    t_res = t_prop = t_fields = t_diff = 0.0
    for i, light in enumerate(scene.lights):
        for ch in range(n_ch):
            prev = old.get((light_key(light), ch))
            if prev is not None:
                j = prev.light_index
                phi[i, ch], phia[i, ch] = reuse.phi[j, ch], reuse.phia[j, ch]
                direct[i, ch] = reuse.direct[j, ch]
                if diffusion:
                    phid[i, ch], flux[i, ch] = reuse.phid[j, ch], reuse.flux[j, ch]
                sols.append(dataclasses.replace(prev, light=light, light_index=i, reused=True))
                continue
            cb = (lambda it, r, i=i: progress(i, it, r)) if progress else None
            point = isinstance(light, PointLight)
            ds = (solve_point_light if point else solve_light)(med, light, scene.method, cb, ch)
            ds.light_index = i
            t0 = time.perf_counter()
            d = ds.domain
            if not point:       # a point light's walk fields are looked up in its own domain
                fields, outs = (ds.result.phi, ds.result.phia), (phi[i, ch], phia[i, ch])
                if ds.direct is not None:        # a sun's unscattered part (environment lights: none)
                    fields, outs = fields + (ds.direct,), outs + (direct[i, ch],)
                domain_to_world(fields, d.frame, d.origin, d.h, med.origin, med.voxel_size, outs, needed)
            if diffusion:
                dr = ds.result.diffusion
                d = ds.diffusion_domain or d
                # world component c of J = sum over the domain axes a of frame[a, c] J_a
                J = np.tensordot(d.frame.T.astype(np.float32), dr.flux, axes=1)
                domain_to_world((dr.phi, J[0], J[1], J[2]), d.frame, d.origin, dr.h, med.origin,
                                med.voxel_size, (phid[i, ch], flux[i, ch, 0], flux[i, ch, 1], flux[i, ch, 2]),
                                needed)
            t_fields += time.perf_counter() - t0
            t_res += ds.seconds_resample
            t_prop += ds.result.seconds
            t_diff += ds.result.seconds_diffusion
            sols.append(ds)
    point = np.array([isinstance(l, PointLight) for l in scene.lights], np.bool_)
    dirs = np.array([[0.0, 0.0, 0.0] if p else l.direction for l, p in zip(scene.lights, point)]).reshape(-1, 3)
    pos = np.array([l.position if p else [0.0, 0.0, 0.0] for l, p in zip(scene.lights, point)]).reshape(-1, 3)
    power = np.array([l.power for l in scene.lights]).reshape(-1, 3)
    return Solution(med, sols, phi, phia, dirs, power,
                    {"resample": t_res, "propagate": t_prop, "diffusion": t_diff, "fields": t_fields},
                    phid, flux, key, pos, point, point_fields(sols, n, n_ch), direct)
