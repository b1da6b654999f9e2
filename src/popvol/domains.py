"""Light-aligned propagation domains (METHOD.md step 2, RECONSTRUCTION.md 2.4).

Directional lights get a rectilinear grid (below); point lights a spherical one
(:class:`SphericalDomain`, further down).

A directional light gets a rectilinear grid of cubic cells whose first axis is the light's
direction of travel d (its principal ordinate); the other two axes u, v complete a right-handed
frame. The grid covers the medium's world AABB (the AABB, in the (d, u, v) frame, of its 8
corners). Slice 0 (index k = 0) faces the light.

Index convention: cell (k, i, j) has its centre at
``origin + ((k + 1/2) d + (i + 1/2) u + (j + 1/2) v) * h`` where ``origin`` is the world
position of the domain's corner. Continuous index coordinates put cell centres at integers.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .errors import PopvolError
from .medium import Medium

#: Working-set bytes per domain cell (float32 arrays): the solvers hold Th, Dh, in-flight W and
#: W*a, accumulated phi and phi*a; Jacobi adds its six outgoing parts (the sweep only small
#: halos). sigma_t, sigma_s and g exist while Th and Dh are computed. Sized for Jacobi.
BYTES_PER_DOMAIN_CELL = 4 * 14


def light_frame(direction: np.ndarray) -> np.ndarray:
    """float64 (3, 3), rows d, u, v: orthonormal, right-handed (v = d x u), d = direction."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    return np.stack([d, u, v])


@dataclass
class DirectionalDomain:
    """A rectilinear domain aligned with a directional light.

    Attributes:
        frame: float64 (3, 3), rows d, u, v (world space).
        origin: float64 (3,), world position of the corner of cell (0, 0, 0).
        h: cell size in world units (cells are cubes).
        shape: (n_d, n_u, n_v) cells.
    """

    frame: np.ndarray
    origin: np.ndarray
    h: float
    shape: tuple[int, int, int]

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    def world_to_index(self, x: np.ndarray) -> np.ndarray:
        """Continuous cell index (centres at integers) of world points x (..., 3)."""
        return (np.asarray(x) - self.origin) @ self.frame.T / self.h - 0.5

    def index_to_world(self, q: np.ndarray) -> np.ndarray:
        """World position of continuous cell index q (..., 3)."""
        return self.origin + (np.asarray(q) + 0.5) * self.h @ self.frame


def directional_domain(medium: Medium, direction: np.ndarray, resolution: int) -> DirectionalDomain:
    """The domain for light travelling along ``direction`` with ``resolution`` cells along its
    longest side; the other sides get the same cell size (rounded up to whole cells)."""
    frame = light_frame(direction)
    lo, hi = medium.bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    local = corners @ frame.T                     # (8, 3) coordinates along d, u, v
    lmin, lmax = local.min(axis=0), local.max(axis=0)
    extent = lmax - lmin
    h = float(extent.max() / resolution)
    shape = tuple(int(max(1, np.ceil(e / h - 1e-9))) for e in extent)
    # centre the (slightly larger) grid on the medium's box
    pad = (np.asarray(shape) * h - extent) / 2
    origin = (lmin - pad) @ frame
    dom = DirectionalDomain(frame, origin, h, shape)
    check_memory(dom.n_cells * BYTES_PER_DOMAIN_CELL, f"{medium.source}: method.resolution = {resolution}",
                 f"a light domain of {shape[0]}x{shape[1]}x{shape[2]} cells")
    return dom


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


def spherical_domain(medium: Medium, position: np.ndarray, resolution: int) -> SphericalDomain:
    """The domain of a point light at ``position``: shells from the medium's box's nearest to
    its farthest point, ``resolution`` cells along the longest of the radial extent and the
    angular extents at the middle radius (for a full sphere, the half circumference), cells
    of about equal size in the three directions at the middle radius."""
    p = np.asarray(position, np.float64)
    lo, hi = medium.bounds
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
                              np.pi / n_t, shape, True)
    else:
        frame = light_frame(axis)
        width = 2 * alpha * r_m
        h = max(r_hi - r_lo, width) / resolution
        n_a = max(1, int(np.ceil(width / h - 1e-9)))
        shape = (max(1, int(np.ceil((r_hi - r_lo) / h - 1e-9))), n_a, n_a)
        dom = SphericalDomain(p, frame, r_lo, (r_hi - r_lo) / shape[0], np.pi / 2 - alpha,
                              2 * alpha / n_a, -alpha, 2 * alpha / n_a, shape, False)
    check_memory(dom.n_cells * BYTES_PER_SPHERICAL_CELL, f"{medium.source}: method.resolution = {resolution}",
                 f"a point light's domain of {shape[0]}x{shape[1]}x{shape[2]} cells")
    return dom


#: Working-set bytes per spherical cell (float32): R, Ra, phi, phia, six direction-dependent
#: factors, sigma_t, sigma_s and g while the factors are made, the hand-over's Q (2) and flags.
BYTES_PER_SPHERICAL_CELL = 4 * 16


def available_memory() -> int:
    """Bytes of memory available to this process now (MemAvailable, else total physical)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(nbytes: int, field: str, what: str) -> None:
    """Raise a PopvolError before allocating ``nbytes`` if it exceeds 80 % of available memory."""
    avail = available_memory()
    if nbytes > 0.8 * avail:
        raise PopvolError(f"{field}: {what} needs about {nbytes / 2**30:.1f} GiB, but only "
                          f"{avail / 2**30:.1f} GiB of memory is available; lower it")
