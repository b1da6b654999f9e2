"""Principal-Ordinate Propagation of a point light (issue "every light", METHOD.md steps 2-5).

Data flow, as for a sun: medium -> the light's spherical domain (domains.SphericalDomain:
cells in r, theta, phi, the principal ordinate radial) -> injection of unit intensity at the
light -> thresholded Gauss-Seidel sweeps along r (kernels/spherical.py) -> fluence phi and
phi*A per cell -> the world grid. The isotropic stage ("diffusion") runs on a rectilinear grid
over the medium: power handed over in the spherical cells is added to the grid cell holding
each cell's centre (its first moment is left out: packets hand over at |a| < the cell's
threshold, handover_scale (1 - exp(-sigma_tr s)), so it is at most that times the power: small
in cells thin on the transport scale, a bias in thick ones, where light drifting outward is
re-emitted isotropically).

For rendering, the walk's fields stay in the spherical domain, multiplied by r^2 (r: distance
to the light): r^2 phi is smooth where phi has the 1/r^2 spike of the light (in vacuum it is I,
constant), so the renderer's trilinear lookup in (r, theta, phi) per sample stays exact near
the light, and it divides by that sample's r^2 (kernels/render.py). The diffusion stage's
fields go to the world grid as a sun's do.

Point lights always use the sweep solver (``method.solver`` = "jacobi" applies to suns only).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from .diffusion import coefficients, solve_diffusion
from .domains import SphericalDomain, directional_domain, spherical_domain
from .kernels import propagation as KP
from .kernels import spherical as KS
from .lights import PointLight
from .medium import Medium
from .propagate import (Budget, DomainSolution, PropagationResult, check_decay, default_max_iterations,
                        direct_fluence,
                        handover_factor, medium_factors, optics, split_table32, sweep_until_converged)
from .propagate import resample_medium as resample_rectilinear
from .scene import Method


def resample_medium(medium: Medium, dom: SphericalDomain, channel: int = 0):
    """sigma_t, sigma_s, g of colour ``channel`` at the spherical cells' centres, float32
    (n_r, n_theta, n_phi) each (per-voxel albedo and g clamped to the edge outside the grid)."""
    def grid(values, clamp):
        out = np.empty(dom.shape, np.float32)
        KS.resample_spherical(values, 1.0 / medium.voxel_size, medium.origin, dom.centre, dom.frame,
                              dom.params, dom.shape, clamp, out)
        return out
    return optics(medium, grid, dom.shape, channel)


def transfer_lengths(dom: SphericalDomain):
    """Lengths of a step along r, theta and phi from each cell's centre, broadcastable to
    the domain's shape: dr, r dtheta, r sin(theta) dphi."""
    r = dom.radii[:, None, None]
    sin_t = np.sin(dom.thetas)[None, :, None]
    return np.full((1, 1, 1), dom.dr), r * dom.dtheta, r * sin_t * dom.dphi


def inverse_area(dom: SphericalDomain) -> np.ndarray:
    """float32 (n_r, n_theta): 1 / (r^2 Omega), the fluence per unit power of a visit."""
    return (1.0 / (dom.radii[:, None] ** 2 * dom.solid_angles[None, :])).astype(np.float32)


def propagate_point(sigma_t, sigma_s, g, dom: SphericalDomain, method: Method, progress=None):
    """Propagate unit intensity from the light through its spherical domain.

    Returns (PropagationResult with phi, phia on the domain, Q0: float32 domain-shaped power
    handed to the isotropic stage, all zero without it). Budget in W per unit intensity
    [W/sr]: the light emits 4 pi (full sphere) or the domain's solid angle.
    """
    shape = dom.shape
    s_r, s_t, s_p = transfer_lengths(dom)
    Tr, Dr = medium_factors(sigma_t, sigma_s, g, s_r, method.decay)
    Tt, Dt = medium_factors(sigma_t, sigma_s, g, s_t, method.decay)
    Tp, Dp = medium_factors(sigma_t, sigma_s, g, s_p, method.decay)
    omega = np.broadcast_to(dom.solid_angles[:, None], shape[1:])
    budget = Budget(injected=float(omega.sum(dtype=np.float64)))
    # pending power at the centres of shell 0: it has crossed half a cell (Tr[0])
    R = np.zeros(shape, np.float32)
    R[0] = omega * Tr[0]
    Ra = R * np.float32(1.0)          # a0 = 1: the light leaves radially
    Ra[0] *= Dr[0]
    budget.absorbed = float(np.sum(omega * (1.0 - Tr[0]), dtype=np.float64))
    phi = np.zeros(shape, np.float32)
    phia = np.zeros(shape, np.float32)
    if method.isotropic == "diffusion":
        # the mean of the radial and the two lateral step lengths
        diffusive = handover_factor(sigma_t, sigma_s, g, (s_r + s_t + s_p) / 3.0)
        Q = np.zeros((2,) + shape, np.float32)
        eps = float(method.handover_scale)
    else:
        diffusive = np.zeros((1, 1, 1), np.float32)
        Q = np.zeros((2, 1, 1, 1), np.float32)
        eps = -1.0
    bands = KP.band_edges(shape[1])
    halo = np.zeros((len(bands) - 1, 2, 2, shape[0], shape[2]), np.float32)
    anti = np.zeros((2,) + shape[1:], np.float32)
    tally_b = np.zeros((len(bands) - 1, 5))
    tally = np.zeros(4)
    table = split_table32()
    moment = method.rule == "moment"
    inv_area = inverse_area(dom)

    def one_sweep(it, w_min):
        with numba.parallel_chunksize(1):     # bands to threads one at a time
            left = KS.sweep(R, Ra, Tr, Tt, Tp, Dr, Dt, Dp, table, moment, dom.full, it % 2 == 0,
                            it % 4 >= 2, np.float32(w_min), inv_area, phi, phia, bands, halo, anti,
                            tally_b, eps, diffusive, Q)
        tally[:] += tally_b[:, :4].sum(axis=0)
        return left, tally_b[:, 4].sum()

    t0 = time.perf_counter()
    target = method.tolerance * budget.injected
    cap = method.max_iterations or default_max_iterations(shape, "sweep")
    in_flight, it = sweep_until_converged(one_sweep, budget.injected, target, cap, R.size,
                                          budget.injected, progress)
    budget.reflected, budget.transmitted, budget.side = (float(x) for x in tally[:3])
    budget.absorbed += float(tally[KP.ABSORBED])
    budget.in_flight = in_flight
    result = PropagationResult(phi, phia, budget, it, it * R.size, in_flight / budget.injected,
                               in_flight <= target, time.perf_counter() - t0)
    return result, (Q[0] if eps > 0 else np.zeros(shape, np.float32))


def diffuse_point(Q0, medium: Medium, dom: SphericalDomain, method: Method, channel: int, result):
    """The isotropic stage of a point light: the handed-over power Q0 (spherical cells) on a
    rectilinear grid over the medium (``method.diffusion_resolution`` cells along its longest
    side, at most ``resolution``: as a sun's diffusion grid), solved by
    diffusion.solve_diffusion. Adds to result's budget; returns (the grid's DirectionalDomain,
    DiffusionResult)."""
    cells = min(method.resolution, method.diffusion_resolution or method.resolution)
    grid = directional_domain(medium, np.array([0.0, 0.0, 1.0]), cells)
    sigma_t, sigma_s, g = resample_rectilinear(medium, grid, channel)
    _, _, region = coefficients(sigma_t, sigma_s, g, grid.h)
    source = np.zeros(grid.shape, np.float32)
    lost = KS.splat_to_grid(Q0, dom.centre, dom.frame, dom.params, grid.origin, grid.h, grid.frame,
                            region, source)
    d = solve_diffusion(source, np.zeros_like(source), sigma_t, sigma_s, g, grid.h,
                        rtol=0.1 * method.tolerance)
    b = result.budget
    b.absorbed += d.absorbed
    b.transmitted += sum(d.leaked[:3])       # out of the grid's faces
    # what was handed over where the grid has no diffusion cell nearby is not propagated
    b.diffusion_leak = d.leaked[3] + lost
    result.diffusion = d
    return grid, d


def solve_point_light(medium: Medium, light: PointLight, method: Method, progress=None,
                      channel: int = 0):
    """Build the light's spherical domain, resample the medium (colour ``channel``) into it,
    propagate unit intensity and, with the diffusion stage, diffuse what was handed over.
    Returns a propagate.DomainSolution (its ``diffusion_domain`` is the rectilinear grid)."""
    check_decay(medium, method)
    t0 = time.perf_counter()
    dom = spherical_domain(medium, light.position, method.resolution)
    sigma_t, sigma_s, g = resample_medium(medium, dom, channel)
    t1 = time.perf_counter()
    result, Q0 = propagate_point(sigma_t, sigma_s, g, dom, method, progress)
    # the unscattered light, r^2 phi_dir = exp(-tau) per unit intensity (tau along the ray from
    # the light, which crosses the shells along k: the same sum as a sun's along its axis)
    direct = direct_fluence(sigma_t, dom.dr) / (dom.radii ** 2)[:, None, None]
    del sigma_t, sigma_s, g
    ds = DomainSolution(light, dom, result, t1 - t0, channel, direct=direct.astype(np.float32))
    if method.isotropic == "diffusion":
        t2 = time.perf_counter()
        ds.diffusion_domain, _ = diffuse_point(Q0, medium, dom, method, channel, result)
        result.seconds_diffusion = time.perf_counter() - t2
    return ds


@dataclass
class PointFields:
    """The walk's fields of every point light's spherical domain, for the renderer, which looks
    them up per sample (kernels/render.py): r^2 phi and r^2 phia (smooth where phi has the
    light's 1/r^2 spike; the renderer divides by each sample's own r^2).

    fields: float32 (2, total): r^2 phi and r^2 phia of every domain (light, channel), each
        block C-ordered (n_r, n_theta, n_phi);
    offset: int64 (n_lights, n_channels): start of each block (-1 for other lights);
    shape: int64 (n_lights, 3); params: float64 (n_lights, 6) (r0, dr, theta0, dtheta, phi0,
    dphi); frame: float64 (n_lights, 3, 3); full: bool (n_lights,) (see SphericalDomain).
    """

    fields: np.ndarray
    offset: np.ndarray
    shape: np.ndarray
    params: np.ndarray
    frame: np.ndarray
    full: np.ndarray


def point_fields(domains, n_lights: int, n_channels: int) -> PointFields:
    """Gather the point lights' domain solutions (propagate.DomainSolution) for the renderer."""
    offset = -np.ones((n_lights, n_channels), np.int64)
    shape = np.ones((n_lights, 3), np.int64)
    params = np.ones((n_lights, 6))
    frame = np.tile(np.eye(3), (n_lights, 1, 1))
    full = np.zeros(n_lights, np.bool_)
    blocks, total = [], 0
    for ds in domains:
        dom = ds.domain
        if not isinstance(dom, SphericalDomain):
            continue
        i = ds.light_index
        r2 = (dom.radii ** 2)[:, None, None]
        blocks.append(np.stack([(ds.result.phi * r2).ravel(), (ds.result.phia * r2).ravel(),
                                (ds.direct * r2).ravel()]))
        offset[i, ds.channel] = total
        total += dom.n_cells
        shape[i], params[i], frame[i], full[i] = dom.shape, dom.params, dom.frame, dom.full
    fields = np.concatenate(blocks, axis=1).astype(np.float32) if blocks else np.zeros((3, 1), np.float32)
    return PointFields(np.ascontiguousarray(fields), offset, shape, params, frame, full)


def no_point_fields(n_lights: int = 0, n_channels: int = 1) -> PointFields:
    return point_fields([], n_lights, n_channels)
