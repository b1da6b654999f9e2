"""A point light and its domain: cells in spherical coordinates about the light, the principal
ordinate radial (docs/METHOD.md, "Walk").

For a light outside the medium's box (experimental.point_walk = "auto", the default; for every
light with "ordinates"; both with solver = "ordinates") the spherical domain holds the
unscattered light only, r^2 phi_dir = exp(-tau) along each radius, and the light's first
scattering is the source of an ordinates walk on a box over the medium, turned toward the
medium as a sun's domain (along the world's axes for a light inside it:
:meth:`SphericalDomain.first_scattering`; docs/METHOD.md, "A point light's ordinates"), whose
fields the renderer reads on the medium's grid, as a sun's scattered light.

Otherwise the walk sweeps along r (kernels/spherical.py) from unit intensity at the light. The
walk's fields stay in the spherical domain, multiplied by r^2, and the renderer looks them up
there per sample (:meth:`SphericalDomain.render_block`). Light handed over goes to a
world-aligned rectilinear grid for the diffusion stage (:meth:`SphericalDomain.hand_over`).
(experimental.solver = "jacobi" and "binned" apply to suns only: a point light sweeps.)
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from .. import check
from ..diffusion import coefficients
from ..domains import (DirectionalDomain, check_memory, directional_domain, light_frame, optics,
                       resample_medium)
from ..errors import PopvolError
from ..kernels import propagation as KP
from ..kernels import spherical as KS
from ..medium import Medium
from ..method import knob_field
from ..results import Budget, WalkResult
from ..walk import (default_max_iterations, direction_split, fibonacci_directions, handover_arrays,
                    medium_factors, never_skipped, scatter_factor, split_table32, sweep_until_converged, walk_box)
from .base import HandOver, Light


@dataclass
class PointLight(Light):
    """An isotropic point light: intensity I [W/sr per RGB channel] in all directions from its
    position; in vacuum its fluence at distance r is I / r^2.

    Attributes:
        position: float64 (3,), world position.
        intensity: float64 (3,), RGB radiant intensity [W/sr], >= 0.
    """

    type: ClassVar[str] = "point"
    keys: ClassVar[frozenset] = frozenset({"type", "position", "intensity"})
    fields_in_domain: ClassVar[bool] = True
    power_field: ClassVar[str] = "intensity"

    position: np.ndarray
    intensity: np.ndarray
    source: str = "<light>"
    from_environment: bool = False

    def __post_init__(self):
        self.position = check.vector(self.position, *self.field("position"))
        self.intensity = check.power(self.intensity, *self.field("intensity"))

    @classmethod
    def from_table(cls, t: dict, name: str, src: str) -> "PointLight":
        if "position" not in t:
            raise PopvolError(f"{src}: {name}.position is required (the light's world position)")
        return cls(t["position"], t.get("intensity", 1.0), source=f"{src}: {name}")

    @property
    def render_position(self) -> np.ndarray:
        return self.position

    def key(self) -> tuple:
        return ("point", tuple(self.position))

    def check(self, medium) -> None:
        name, src = self.field("position")
        check_point_distance(medium, self.position, f"{src}: {name}")

    def domain(self, medium, method) -> "SphericalDomain":
        """Its spherical domain; with the ordinates' walks and ``method.point_walk =
        "ordinates"`` (or "auto" where the light is outside the medium's box, its domain a
        cone), with a box over the medium for its scattered light
        (``method.resolution`` cells along its longest side, cropped as a sun's): turned, as a
        sun's domain, toward the medium (along the cone's axis) where the light is outside the
        medium's box, so that its light crosses the lattice as nearly along an ordinate as a
        cone allows; along the world's axes (BOX_AXIS) where the domain is the whole sphere."""
        field = knob_field(method, "resolution", medium.source)
        sphere = spherical_domain(medium, self.position, method.resolution, field)
        walk = method.point_walk
        if method.solver == "ordinates" and (walk == "ordinates" or (walk == "auto" and not sphere.full)):
            axis = BOX_AXIS if sphere.full else sphere.frame[0]
            sphere.grid = directional_domain(medium, axis, method.resolution, field=field)
        return sphere

    def table(self) -> dict:
        return {"type": self.type, "position": [float(x) for x in self.position],
                "intensity": [float(x) for x in self.intensity]}

    def mitsuba(self) -> dict:
        # intensity [W/sr] in both
        return {"type": "point", "position": self.position.tolist(),
                "intensity": {"type": "rgb", "value": self.intensity.tolist()}}

    def digest(self) -> bytes:
        return b"point" + np.concatenate([self.position, self.intensity]).astype(np.float64).tobytes()

@dataclass
class SphericalDomain:
    """A point light's domain: cells in spherical coordinates (r, theta, phi) about the light,
    the principal ordinate radial (index k along r, as a directional domain's k runs along d).

    The direction of (theta, phi) is ``sin(theta) cos(phi) e1 + sin(theta) sin(phi) e2 +
    cos(theta) e3`` with frame rows e1, e2, e3. Cell (k, i, j) spans r in r0 + [k, k + 1] dr,
    theta in theta0 + [i, i + 1] dtheta, phi in phi0 + [j, j + 1] dphi; its centre is at the
    middle of each range.

    Two layouts:
      * ``full`` (light inside the medium's box or close to it): the whole sphere, theta in
        [0, pi], phi in [0, 2 pi) periodic; n_phi is even so that a step across a pole lands in
        the cell opposite (phi + pi), and light sent back through the inner sphere comes out
        of the antipodal cell.
      * otherwise, a cone about the axis e1 (from the light to the box's centre) that holds the
        box: latitude and longitude both in [-alpha, alpha] about e1 (theta = pi/2 - latitude),
        so no pole is inside it; its lateral faces are open.

    Attributes:
        centre: float64 (3,), the light's position.
        frame: float64 (3, 3), rows e1, e2, e3 (orthonormal, right-handed).
        r0, dr, theta0, dtheta, phi0, dphi: floats (world units and radians).
        shape: (n_r, n_theta, n_phi).
        full: the whole sphere (see above).
        box: float64 (2, 3), the medium's box (lo, hi), or None. The box is convex, so light
            that has left it never comes back: the sweep counts what reaches a cell well
            beyond it as escaped instead of walking it on through empty space (exit_shells).
        grid: with the ordinates' walks, the rectilinear domain over the medium on which the
            light that scattered is walked (:meth:`walk`); None: the sweeps walk it all here.
    """

    centre: np.ndarray
    frame: np.ndarray
    r0: float
    dr: float
    theta0: float
    dtheta: float
    phi0: float
    dphi: float
    shape: tuple[int, int, int]
    full: bool
    box: np.ndarray | None = None
    grid: DirectionalDomain | None = None

    def exit_shells(self) -> np.ndarray:
        """int32 (n_theta, n_phi): per ray of cells, the first shell beyond the medium's box
        (kernels.spherical.exit_shells), where light that arrives has left the box for good;
        n_r everywhere without a box."""
        if self.box is None:
            return np.full(self.shape[1:], self.shape[0], np.int32)
        return KS.exit_shells(self.centre, self.frame, self.params, np.array(self.shape, np.int64),
                              self.box[0], self.box[1])

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def radii(self) -> np.ndarray:
        """float64 (n_r,): the radius of each shell's cell centres."""
        return self.r0 + (np.arange(self.shape[0]) + 0.5) * self.dr

    @property
    def thetas(self) -> np.ndarray:
        return self.theta0 + (np.arange(self.shape[1]) + 0.5) * self.dtheta

    @property
    def solid_angles(self) -> np.ndarray:
        """float64 (n_theta,): the exact solid angle of a cell of each row,
        (cos theta_lo - cos theta_hi) dphi; they sum to 4 pi over a full sphere."""
        edges = self.theta0 + np.arange(self.shape[1] + 1) * self.dtheta
        return (np.cos(edges[:-1]) - np.cos(edges[1:])) * self.dphi

    @property
    def params(self) -> np.ndarray:
        """float64 (6,): r0, dr, theta0, dtheta, phi0, dphi (what the kernels take)."""
        return np.array([self.r0, self.dr, self.theta0, self.dtheta, self.phi0, self.dphi])

    def index_to_world(self, q: np.ndarray) -> np.ndarray:
        """World position of continuous cell index q (..., 3) (centres at integers)."""
        q = np.asarray(q, np.float64)
        r = self.r0 + (q[..., 0] + 0.5) * self.dr
        t = self.theta0 + (q[..., 1] + 0.5) * self.dtheta
        p = self.phi0 + (q[..., 2] + 0.5) * self.dphi
        local = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
        return self.centre + r[..., None] * (local @ self.frame)

    @property
    def cell_size(self) -> float:
        return self.dr

    def transfer_lengths(self):
        """Lengths of a step along r, theta and phi from each cell's centre, broadcastable to
        the domain's shape: dr, r dtheta, r sin(theta) dphi (kernels.spherical.face_factors
        computes them per face; tests/test_point.py checks its factors against these)."""
        r = self.radii[:, None, None]
        sin_t = np.sin(self.thetas)[None, :, None]
        return np.full((1, 1, 1), self.dr), r * self.dtheta, r * sin_t * self.dphi

    def inverse_area(self) -> np.ndarray:
        """float32 (n_r, n_theta): 1 / (r^2 Omega), the fluence per unit power of a visit."""
        return (1.0 / (self.radii[:, None] ** 2 * self.solid_angles[None, :])).astype(np.float32)

    def resample(self, medium, channel: int = 0):
        """sigma_t, sigma_s, g of colour ``channel`` at the cells' centres, float32
        (n_r, n_theta, n_phi) each (per-voxel albedo and g clamped to the edge outside the
        grid); with a ``grid``, a fourth item: its own (domains.resample_medium)."""
        def grid(values, clamp):
            out = np.empty(self.shape, np.float32)
            KS.resample_spherical(values, 1.0 / medium.voxel_size, medium.origin, self.centre,
                                  self.frame, self.params, self.shape, clamp, out)
            return out
        sphere = optics(medium, grid, self.shape, channel)
        return sphere if self.grid is None else sphere + (resample_medium(medium, self.grid, channel),)

    def cells_read(self, medium, seen):
        """The ``grid``'s cells read (its walk skips the empty space outside them), or None
        without one: the sweeps visit every cell (the renderer reads their fields here)."""
        return None if self.grid is None else self.grid.cells_read(medium, seen)

    def spherical(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, theta, phi), float64 (m,) each, of world points x (m, 3) (kernels.spherical's
        spherical_index, in NumPy; phi in [0, 2 pi) on a full sphere)."""
        local = (np.asarray(x, np.float64) - self.centre) @ self.frame.T
        r = np.linalg.norm(local, axis=1)
        theta = np.arccos(np.clip(local[:, 2] / np.maximum(r, 1e-300), -1.0, 1.0))
        phi = np.arctan2(local[:, 1], local[:, 0])
        if self.full:
            phi = np.where(phi < 0.0, phi + 2.0 * np.pi, phi)
        return r, theta, phi

    def lookup(self, field: np.ndarray, x: np.ndarray) -> np.ndarray:
        """float64 (m,): ``field`` (the domain's shape) at world points x (m, 3), trilinear in
        the continuous cell index, clamped in r and theta, periodic in phi on a full sphere (the
        renderer's kernels.render.point_lookup, in NumPy)."""
        r, theta, phi = self.spherical(x)
        q = ((r - self.r0) / self.dr - 0.5, (theta - self.theta0) / self.dtheta - 0.5,
             (phi - self.phi0) / self.dphi - 0.5)
        corners = []
        for axis, (qa, n) in enumerate(zip(q, self.shape)):
            if axis == 2 and self.full:
                lo = np.floor(qa)
                f = qa - lo
                i0 = lo.astype(np.int64) % n
                corners.append((i0, (i0 + 1) % n, f))
            else:
                qa = np.clip(qa, 0.0, n - 1.0)
                i0 = np.minimum(qa.astype(np.int64), max(n - 2, 0))
                corners.append((i0, np.minimum(i0 + 1, n - 1), qa - i0))
        out = np.zeros(len(r))
        for a in range(8):
            k, i, j = (c[1] if a & bit else c[0] for c, bit in zip(corners, (4, 2, 1)))
            w = np.ones(len(r))
            for c, bit in zip(corners, (4, 2, 1)):
                w *= c[2] if a & bit else 1.0 - c[2]
            out += w * field[k, i, j]
        return out

    def first_scattering(self, direct: np.ndarray, sigma_t: np.ndarray, sigma_s: np.ndarray, grid_g: np.ndarray,
                         cells: np.ndarray, n_ordinates: int):
        """The light's first scattering, per unit intensity, as packets pending at the centres
        of the ``grid``'s ``cells`` (bool, its shape: walk.never_skipped, the cells with medium
        in or beside them), split among the ordinates (walk.place's source: index, power,
        moment); ``grid_g`` (float32, its shape) the phase's anisotropy there.

        Each cell of this domain scatters ``(sigma_s / sigma_t) (E_in - E_out) Omega``, E =
        exp(-tau) where its ray enters and leaves it (``direct`` times r^2 at its centre, times
        exp(+-sigma_t dr / 2)), so the power first scattered along a ray adds up to the albedo
        times what the ray loses, however thick the cells. That over the cell's volume, times
        r^2, is smooth (sigma_s exp(-tau) in a thin cell) and is interpolated to the grid's
        centres (:meth:`lookup`); a grid cell scatters it times 1 / r^2 h^3 at its centre, or,
        where that is within NEAR_CELLS cells of the light (whose light is first scattered
        mostly near it), what the rays lose inside it (:meth:`scattered_in_cubes`). Its lobe,
        HG_g about the light's direction n, is split as the walks split a lobe
        (walk.direction_split)."""
        grid = self.grid
        g = grid_g
        lo = self.r0 + np.arange(self.shape[0]) * self.dr
        hi = lo + self.dr
        r = self.radii
        albedo = np.where(sigma_t > 0.0, sigma_s / np.maximum(sigma_t, 1e-30), 0.0)
        loss = 2.0 * direct * np.sinh(0.5 * sigma_t * self.dr)        # (E_in - E_out) / r^2
        density = albedo * loss * (3.0 * r ** 4 / (hi ** 3 - lo ** 3))[:, None, None]
        index = np.nonzero(cells)
        x = grid.index_to_world(np.stack(index, axis=-1).astype(np.float64))
        d = x - self.centre
        dist = np.linalg.norm(d, axis=1)
        inv_r2 = 1.0 / np.maximum(dist * dist, 1e-300)      # cells near the light: scattered_in_cubes
        power = self.lookup(density, x) * inv_r2 * grid.h ** 3
        near = np.flatnonzero(dist < NEAR_CELLS * grid.h)
        if near.size:
            power[near] = self.scattered_in_cubes(sigma_t, sigma_s, d[near] @ grid.frame.T, grid.h)
        keep = power > 0.0
        n = np.where(dist[:, None] > 0.0, d / np.maximum(dist, 1e-300)[:, None], [1.0, 0.0, 0.0]) @ grid.frame.T
        index = tuple(i[keep] for i in index)
        share, moment = direction_split(n[keep], g[index], n_ordinates)
        power = power[keep, None].astype(np.float32)
        return np.array(index), share * power, moment * power

    def scattered_in_cubes(self, sigma_t: np.ndarray, sigma_s: np.ndarray, centres: np.ndarray,
                           h: float) -> np.ndarray:
        """float64 (m,): the power first scattered per unit intensity in cubes of side h at
        ``centres`` (m, 3, relative to the light, in the frame of the cubes' axes, which are
        the grid's), ``int dOmega albedo (exp(-tau_in) - exp(-tau_out))`` over the rays from
        the light (:func:`cube_chords`, NEAR_DIRECTIONS of them), tau this domain's (sigma_t
        constant in each cell: linear along r within a shell), the albedo of the cell where
        the ray leaves the cube's middle."""
        omega = fibonacci_directions(NEAR_DIRECTIONS)
        world = omega @ self.grid.frame                  # the directions in the world
        depth = np.cumsum(sigma_t * self.dr, axis=0) - sigma_t * self.dr   # tau at each shell's inner face
        albedo = np.where(sigma_t > 0.0, sigma_s / np.maximum(sigma_t, 1e-30), 0.0)

        def cell_at(t, w):
            """The cell (k, i, j) holding the points at distance t along the rays w (in the
            world), and how far into its shell each lies."""
            r, theta, phi = self.spherical(self.centre + t[:, None] * w)
            idx = [np.clip(np.floor((v - v0) / dv).astype(np.int64), 0, n - 1)
                   for v, v0, dv, n in ((r, self.r0, self.dr, self.shape[0]),
                                        (theta, self.theta0, self.dtheta, self.shape[1]),
                                        (phi, self.phi0, self.dphi, self.shape[2]))]
            return tuple(idx), np.clip(r - self.r0 - idx[0] * self.dr, 0.0, self.dr)

        def transmittance(t, w):
            cell, into = cell_at(t, w)
            return np.exp(-(depth[cell] + sigma_t[cell] * into))

        out = np.empty(len(centres))
        for c, centre in enumerate(np.asarray(centres, np.float64)):
            t_in, t_out = cube_chords(centre, h, omega)
            hit = t_out > t_in
            a, b, w = t_in[hit], t_out[hit], world[hit]
            cell, _ = cell_at(0.5 * (a + b), w)
            out[c] = 4.0 * np.pi / NEAR_DIRECTIONS * np.sum(albedo[cell] * (transmittance(a, w) - transmittance(b, w)))
        return out

    def walk(self, optics, method, progress=None, read=None) -> WalkResult:
        """Walk unit intensity from the light out through the shells (by sweeps), or, with a
        ``grid``, walk its first scattering there by the ordinates (:meth:`walk_scattered`).
        Budget in W per unit intensity [W/sr]: the light emits 4 pi (full sphere) or the
        domain's solid angle. ``direct`` holds the unscattered fluence, ``handed`` (with the
        diffusion stage) the handed-over power and moment."""
        if self.grid is not None:
            return self.walk_scattered(optics, method, progress, read)
        sigma_t, sigma_s, g = optics
        shape = self.shape
        # the sweeps read each face's (T, D), the product of its two cells' half steps
        faces = KS.empty_faces(shape)
        factor = np.empty(shape, np.float32)
        KS.face_factors(sigma_t, sigma_s, g, self.params, method.decay == "paper", self.full, *faces, factor)
        omega = np.broadcast_to(self.solid_angles[:, None], shape[1:])
        budget = Budget(injected=float(omega.sum(dtype=np.float64)))
        # pending power at the centres of shell 0: it has crossed half a cell (T0, D0)
        T0, D0 = medium_factors(sigma_t[0], sigma_s[0], g[0], self.dr, method.decay)
        R = np.zeros(shape, np.float32)
        R[0] = omega * T0
        Ra = R * np.float32(1.0)          # a0 = 1: the light leaves radially
        Ra[0] *= D0
        budget.absorbed = float(np.sum(omega * (1.0 - T0), dtype=np.float64))
        phi = np.zeros(shape, np.float32)
        phia = np.zeros(shape, np.float32)
        handover = None
        if method.isotropic == "diffusion":
            # the threshold of the mean of the radial and the two lateral step lengths
            handover = (method.handover_scale, factor)
        eps, diffusive, Q = handover_arrays(handover, shape)
        bands = KP.band_edges(shape[1])
        halo = np.zeros((len(bands) - 1, 2, 2, shape[0], shape[2]), np.float32)
        anti = np.zeros((2,) + shape[1:], np.float32)
        tally_b = np.zeros((len(bands) - 1, 5))
        tally = np.zeros(4)
        table = split_table32()
        moment = method.rule == "moment"
        inv_area = self.inverse_area()
        k_end = self.exit_shells()

        visited = np.array([(k_end[lo:hi].max(initial=1)) * (hi - lo) * shape[2]
                            for lo, hi in zip(bands[:-1], bands[1:])], np.float64)

        def one_sweep(it, w_min):
            # the bands dealt to the threads by the work each did in the sweep before
            band_lane = KP.band_lanes(tally_b[:, 4], visited, numba.get_num_threads())
            left = KS.sweep(R, Ra, *faces, table, moment, self.full, it % 2 == 0,
                            it % 4 >= 2, np.float32(w_min), inv_area, phi, phia, bands, band_lane, halo, anti,
                            tally_b, eps, diffusive, Q, k_end)
            tally[:] += tally_b[:, :4].sum(axis=0)
            return left, tally_b[:, 4].sum()

        t0 = time.perf_counter()
        target = method.tolerance * budget.injected
        cap = method.max_iterations or default_max_iterations(shape, "sweep")
        in_flight, it, sent = sweep_until_converged(one_sweep, budget.injected, target, cap, R.size,
                                                    budget.injected, progress)
        budget.reflected, budget.transmitted, budget.side = (float(x) for x in tally[:3])
        budget.absorbed += float(tally[KP.ABSORBED])
        budget.in_flight = in_flight
        return WalkResult(phi, phia, budget, it, it * R.size, in_flight / budget.injected,
                          in_flight <= target, time.perf_counter() - t0, direct=self.direct_fluence(sigma_t),
                          handed=Q if handover is not None else None, cells_sent=sent)

    def walk_scattered(self, optics, method, progress=None, read=None) -> WalkResult:
        """The ordinates' walk (method.ordinates) of the light's first scattering
        (:meth:`first_scattering`) on the ``grid`` (``read``: its cells read, whose fields the
        renderer needs; the empty space outside them is crossed without visits): every order
        of the scattered light, with no hand-over. Returns the unscattered fluence as phi,
        phia and direct here, and the grid's walk as ``scattered``, whose budget (in W per unit
        intensity: injected is the power that first scattered) the result takes."""
        sigma_t, sigma_s, _, grid_optics = optics
        t0 = time.perf_counter()
        direct = self.direct_fluence(sigma_t)
        grid_t, grid_s, grid_g = grid_optics
        Th, Dh = medium_factors(grid_t, grid_s, grid_g, self.grid.h, method.decay)
        Sh = scatter_factor(grid_s, self.grid.h)
        source = self.first_scattering(direct, sigma_t, sigma_s, grid_g, never_skipped(Th, Dh, Sh), method.ordinates)
        walk = walk_box(Th, Dh, None, 1.0, self.grid.h, method.rule, "ordinates", method.tolerance,
                        method.max_iterations, progress=progress, scatter=Sh, read=read, ordinates=method.ordinates,
                        source=source)
        return WalkResult(direct.copy(), direct.copy(), walk.budget, walk.iterations, walk.cell_updates,
                          walk.residual, walk.converged, time.perf_counter() - t0, "ordinates", direct=direct,
                          cells_sent=walk.cells_sent, scattered=walk)

    def direct_fluence(self, sigma_t):
        """The unscattered fluence at the cell centres per unit intensity, float32 (the domain's
        shape): r^2 phi_dir = exp(-tau), tau along the ray from the light, which crosses the
        shells along k (the same sum as a sun's along its axis)."""
        out = np.empty(self.shape, np.float32)
        KS.direct_fluence(sigma_t, self.params, out)
        out /= (self.radii ** 2).astype(np.float32)[:, None, None]
        return out

    def hand_over(self, walk, optics, medium, method, channel: int = 0) -> HandOver:
        """The handed-over power on a world-aligned rectilinear grid over the medium
        (``method.diffusion_resolution`` cells along its longest side, at most ``resolution``):
        each spherical cell's power goes to the grid cell holding its centre. Its first moment is
        left out: packets hand over at |a| below the cell's threshold, so it is at most that
        times the power (a bias in cells thick on the transport scale). What the grid has no
        diffusion cell for nearby is ``lost``."""
        cells = min(method.resolution, method.diffusion_resolution or method.resolution)
        grid = directional_domain(medium, np.array([0.0, 0.0, 1.0]), cells)
        grid_optics = resample_medium(medium, grid, channel)
        _, _, region = coefficients(*grid_optics, grid.h)
        source = np.zeros(grid.shape, np.float32)
        lost = KS.splat_to_grid(walk.handed[0], self.centre, self.frame, self.params, grid.origin,
                                grid.h, grid.frame, region, source)
        # the grid's faces are not the domain's: all that leaves them is transmitted
        return HandOver(grid, source, np.zeros_like(source), grid_optics, 1,
                        ("transmitted",) * 3, lost)

    def world_fields(self, walk, medium, needed, outs, also=()) -> None:
        """Nothing: the renderer looks the walk's fields up in this domain (render_block). Its
        diffusion grid is not the domain, so ``also`` is empty."""
        if also:
            raise ValueError("a spherical domain has no fields on its own cells to map to the world grid")

    def render_block(self, walk) -> np.ndarray:
        """float32 (3, n_cells): r^2 phi, r^2 phia and r^2 phi_dir, C-ordered (n_r, n_theta,
        n_phi): smooth where phi has the light's 1/r^2 spike (in vacuum r^2 phi = I), so the
        renderer's trilinear lookup per sample stays exact near the light."""
        r2 = (self.radii ** 2).astype(np.float32)[:, None, None]
        block = np.empty((3,) + self.shape, np.float32)
        for row, field in zip(block, (walk.phi, walk.phia, walk.direct)):
            np.multiply(field, r2, out=row)
        return block.reshape(3, -1)


#: cells whose centre is nearer a point light than this many cells get the power its rays lose in
#: them (SphericalDomain.scattered_in_cubes) as its first scattering, not a centre value
NEAR_CELLS = 2.0
#: directions of the quadratures over the rays through a cell near a point light
NEAR_DIRECTIONS = 4096


def cube_chords(centre: np.ndarray, h: float, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays from the origin along ``omega`` (n, 3) enter and leave the axis-aligned
    cube of side h at ``centre`` (3,): float64 (n,) each, t_in >= 0 (0 where the cube holds the
    origin); t_out <= t_in where a ray misses it."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / omega                                           # inf where 0
        t1 = (centre - 0.5 * h) * inv
        t2 = (centre + 0.5 * h) * inv
        lo = np.nanmax(np.minimum(t1, t2), axis=1)
        hi = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.maximum(lo, 0.0), hi


#: the axis of the box a point light's scattered light is walked on where its domain is the whole
#: sphere (domains.light_frame: rows z, x, y, so its cells are the medium's axes)
BOX_AXIS = np.array([0.0, 0.0, 1.0])
#: A cone wider than this (half-angle) becomes a full sphere: its corners would be too distorted.
MAX_CONE_HALF_ANGLE = np.radians(60.0)
#: Point lights farther than this many medium diagonals are refused (use a sun): the float32
#: fields could not hold r^2 phi and 1 / r^2 much beyond it.
MAX_POINT_DISTANCE = 1e6


def check_point_distance(medium: Medium, position: np.ndarray, field: str) -> None:
    """Refuse a point light farther than MAX_POINT_DISTANCE medium diagonals from the medium."""
    p = np.asarray(position, np.float64)
    lo, hi = medium.bounds
    diagonal = float(np.linalg.norm(hi - lo))
    gap = np.abs(p - np.clip(p, lo, hi)).max()         # before any square can overflow
    if not gap <= MAX_POINT_DISTANCE * diagonal:
        raise PopvolError(f"{field}: a point light at {p.tolist()} is {gap:.3g} units from the "
                          f"medium, more than {MAX_POINT_DISTANCE:g} times its size ({diagonal:.3g}); "
                          "its light arrives as parallel as a sun's: use a directional light")


def spherical_domain(medium: Medium, position: np.ndarray, resolution: int, field: str | None = None
                     ) -> SphericalDomain:
    """The domain of a point light at ``position``: shells from the medium's box's nearest to
    its farthest point, ``resolution`` cells along the longest of the radial extent and the
    angular extents at the middle radius (for a full sphere, the half circumference), cells
    of about equal size in the three directions at the middle radius. ``field``: how a message
    about its memory names the resolution (popvol.method.knob_field)."""
    p = np.asarray(position, np.float64)
    lo, hi = medium.bounds
    box = np.array([lo, hi], np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    check_point_distance(medium, p, medium.source)
    rel = corners - p
    r_hi = float(np.linalg.norm(rel, axis=1).max())
    r_lo = float(np.linalg.norm(p - np.clip(p, lo, hi)))
    axis = (lo + hi) / 2 - p
    alpha = np.pi
    if r_lo > 0:
        axis = axis / np.linalg.norm(axis)
        # the angle of each corner from the axis; arctan2 keeps small angles accurate
        sines = np.linalg.norm(np.cross(rel, axis), axis=1)
        alpha = float(np.arctan2(sines, rel @ axis).max()) * (1 + 1e-6)
    r_m = 0.5 * (r_lo + r_hi)
    if alpha > MAX_CONE_HALF_ANGLE:
        # poles along world y; e1 x e2 = e3
        frame = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
        h = max(r_hi - r_lo, np.pi * r_m) / resolution
        n_t = max(2, int(np.ceil(np.pi * r_m / h - 1e-9)))
        shape = (max(1, int(np.ceil((r_hi - r_lo) / h - 1e-9))), n_t, 2 * n_t)
        dom = SphericalDomain(p, frame, r_lo, (r_hi - r_lo) / shape[0], 0.0, np.pi / n_t, 0.0,
                              np.pi / n_t, shape, True, box)
    else:
        frame = light_frame(axis)
        width = 2 * alpha * r_m
        h = max(r_hi - r_lo, width) / resolution
        n_a = max(1, int(np.ceil(width / h - 1e-9)))
        shape = (max(1, int(np.ceil((r_hi - r_lo) / h - 1e-9))), n_a, n_a)
        dom = SphericalDomain(p, frame, r_lo, (r_hi - r_lo) / shape[0], np.pi / 2 - alpha,
                              2 * alpha / n_a, -alpha, 2 * alpha / n_a, shape, False, box)
    check_memory(dom.n_cells * BYTES_PER_SPHERICAL_CELL, field or f"{medium.source}: method.resolution = {resolution}",
                 f"a point light's domain of {shape[0]}x{shape[1]}x{shape[2]} cells")
    return dom


#: Working-set bytes per spherical cell (float32): R, Ra, phi, phia, six direction-dependent
#: factors, sigma_t, sigma_s and g while the factors are made, the hand-over's Q (2) and flags.
BYTES_PER_SPHERICAL_CELL = 4 * 16
