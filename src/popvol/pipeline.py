"""Solving a scene: every light, the same steps (docs/METHOD.md):

    light domain -> resample the medium -> walk -> hand-over -> diffusion -> world fields

Each light kind supplies its domain (popvol.lights); this module runs the steps, books the
energy budget the same way for every kind, and gathers the fields the renderer reads.

Grey media are linear in the light's power (the anisotropy merge is energy-weighted, so it is
independent of scale): each domain is solved once for unit irradiance (or intensity) and the
renderer scales it by the light's RGB power. A chromatic medium is solved once per channel.

The domains are independent until their fields are gathered, so where it pays (a sky's many
small domains: :func:`side_by_side`) they are solved side by side, each on a Python thread with
its share of Numba's threads (the kernels release the GIL); every kernel gives the same bits on
any number of threads, so the solution is the same either way.
"""
from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from .diffusion import solve_diffusion, warm_guess
from .domains import (BYTES_PER_DOMAIN_CELL, available_memory, check_memory, directional_domain, frame_to_world,
                      grow, resample_medium, small_pages)
from .errors import PopvolError
from .kernels.render import MAX_DIFFUSE_ANISOTROPY
from .kernels.sampling import domain_to_world
from .lights.point import BYTES_PER_SPHERICAL_CELL
from .results import DomainSolution, PointFields, Solution
from .walk import direct_fluence, replace_direct


#: one domain solved on n threads runs about PARALLEL_EFFICIENCY n times as fast as on one, for
#: side_by_side (measured on 2 threads, solving side by side against one domain at a time: the
#: bench's wdas_sun_sky x0.80, the demo x0.74, demo_dusk x0.94 and wdas_side x0.84 of the time,
#: which these scenes' cells put at 0.65-0.8)
PARALLEL_EFFICIENCY = 0.7
#: a domain's working set per cell, at most (a spherical or a box domain's)
BYTES_PER_CELL = max(BYTES_PER_SPHERICAL_CELL, BYTES_PER_DOMAIN_CELL)


def check_decay(medium, method) -> None:
    """decay = 'paper' raises g to a power: it needs g >= 0 everywhere."""
    if method.decay == "paper" and medium.g_min < 0:
        raise PopvolError(f"{medium.source}: experimental.decay = 'paper' (g^(sigma_s s), supplement "
                          f"Eq. 12) needs g >= 0, got g = {medium.g_min:g}; use decay = 'poisson'")


def solve_light(medium, light, method, progress=None, channel: int = 0, warm: DomainSolution | None = None,
                transport=None, domain=None) -> DomainSolution:
    """Build the light's domain (or take ``domain``, ``light.domain(medium, method)`` built
    before), resample the medium (colour ``channel``) into it, walk unit
    power and, with the diffusion stage, diffuse what was handed over. Light transport sees
    ``transport`` (None: ``medium.transport_medium()``, voxels thicker than its transport_depth_cap()
    mean free paths capped); the unscattered light (``direct``) the medium itself.

    ``warm``: the same light's domain solution from an earlier frame (see :func:`solve`): its
    diffusion fluence is the conjugate-gradient solve's initial guess, resampled if the grid
    moved or changed shape (``warm_note`` says which, or why cold).
    The walk always starts cold (see :func:`solve`)."""
    check_decay(medium, method)
    t0 = time.perf_counter()
    transport = medium.transport_medium() if transport is None else transport
    domain = light.domain(medium, method) if domain is None else domain
    optics = domain.resample(transport, channel)
    # the cells whose fields are mapped onto the voxels the renderer reads: the six-ordinate
    # walk crosses empty cells outside them without visiting them (docs/METHOD.md, "Skipping
    # empty space")
    read = domain.cells_read(medium, seen_voxels(medium)) if method.solver == "ordinates" else None
    t1 = time.perf_counter()
    walk = domain.walk(optics, method, progress, read)
    if transport is not medium and walk.direct is not None and light.unscattered:
        # the unscattered light crosses the true density (docs/METHOD.md, "Optically thick voxels");
        # the walk's own, through the capped density, is kept for the gathered last bounce (Eq. 25g)
        # (an environment region's unscattered lobe is read by that alone: it keeps the walk's)
        capped = walk.direct
        replace_direct(walk, domain.direct_fluence(domain.resample(medium, channel)[0]))
        walk.direct_transport = capped
    ds = DomainSolution(light, domain, walk, t1 - t0, channel)
    if walk.handed is not None:         # the diffusion stage (not for a sun's six-ordinate walk)
        t2 = time.perf_counter()
        hand = domain.hand_over(walk, optics, transport, method, channel)
        x0 = None
        if warm is not None:
            prev = warm.result.diffusion
            x0, ds.warm_note = warm_guess(prev, warm.diffusion_grid, hand.grid, hand.factor)
            ds.warm = x0 is not None
        d = solve_diffusion(hand.Q0, hand.Q1, *hand.optics, hand.grid.h, rtol=0.1 * method.tolerance,
                            factor=hand.factor, x0=x0)
        walk.budget.add_diffusion(d, hand.faces, hand.lost)
        walk.diffusion, walk.handed = d, None
        ds.diffusion_grid = hand.grid
        walk.seconds_diffusion = time.perf_counter() - t2
    elif warm is not None:
        ds.warm_note = "cold: no diffusion stage (the walk always starts cold)"
    return ds


def broad_lobe_a0(sols: list, n_lights: int) -> np.ndarray:
    """float64 (n_lights,): each light's a0 where its domains kept a broad lobe's unscattered
    part in ``direct`` (an environment region walked by the ordinates: WalkResult.direct_a0 <
    1; Solution.lobe_a0), else 0."""
    out = np.zeros(n_lights)
    for ds in sols:
        r = ds.result
        if r.direct is not None and r.direct_a0 < 1.0 and r.flux is not None:
            out[ds.light_index] = r.direct_a0
    return out


def side_by_side(cells: list[int], threads: int | None = None, memory: float | None = None) -> int:
    """How many domains to solve at once, each on threads // that many of Numba's ``threads``
    (None: numba.get_num_threads()): as many as there are (at most ``threads``) where the jobs
    dealt out largest first, each to the worker with the least work so far, finish before the
    same jobs one at a time on every thread would (a domain's cells standing for its work; one
    domain on n > 1 threads runs PARALLEL_EFFICIENCY n times as fast as on one) and the largest
    of them fit in 80 % of ``memory`` bytes together (None: the memory available now; each cell
    at BYTES_PER_CELL); else 1. The result does not depend on it (every kernel gives the same
    bits on any number of threads)."""
    threads = numba.get_num_threads() if threads is None else threads
    workers = min(threads, len(cells))
    if workers < 2:
        return 1
    memory = available_memory() if memory is None else memory
    if sum(sorted(cells, reverse=True)[:workers]) * BYTES_PER_CELL > 0.8 * memory:
        return 1
    load = [0] * workers
    for c in sorted(cells, reverse=True):
        load[load.index(min(load))] += c
    speed = lambda n: 1.0 if n == 1 else PARALLEL_EFFICIENCY * n
    return workers if max(load) / speed(threads // workers) < sum(cells) / speed(threads) else 1


def run_jobs(fn, cells: list[int], workers: int) -> list:
    """[fn(k) for k in range(len(cells))], with ``workers`` > 1 on as many Python threads, the
    largest jobs (``cells``) first, each thread with threads // workers of Numba's threads
    (numba.set_num_threads is per thread; the kernels release the GIL). A job's error (or
    Ctrl-C) is raised once the jobs running finish; the jobs not started are dropped."""
    if workers < 2:
        return [fn(k) for k in range(len(cells))]
    each = max(numba.get_num_threads() // workers, 1)
    pool = ThreadPoolExecutor(workers, initializer=numba.set_num_threads, initargs=(each,))
    try:
        futures = {k: pool.submit(fn, k) for k in sorted(range(len(cells)), key=lambda k: -cells[k])}
        return [futures[k].result() for k in range(len(cells))]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def ordinate_fields(walk, dom, medium, needed, outs, phid, flux) -> None:
    """The six-ordinate walk's fields on the medium's grid (docs/METHOD.md, "Six ordinates"):
    its unscattered light as the walk's lobe (outs = phi, phia, phi_dir, all set to phi_dir,
    a delta along the light) and the rest, phi - phi_dir (at least 0) with first moment
    F - phi_dir d, as one lobe about its own moment in ``phid`` and ``flux`` (float32 (3, nx,
    ny, nz), world frame), which the renderer lights with the diffuse lobe capped at 1 (the
    walk has no diffusion stage). A broad lobe's unscattered part (an environment's light,
    ``walk.direct_a0`` < 1) is no delta lobe: phid and flux keep all its light, and its
    unscattered part goes to outs[2] (phi_dir) alone, for the gathered last bounce (Eq. 26a);
    without one (``walk.direct`` None) its ``outs`` are left as they are (zeros)."""
    direct = walk.direct
    F = walk.flux
    collimated = direct is not None and walk.direct_a0 == 1.0
    if collimated:
        rest = np.maximum(walk.phi - direct, 0.0)
        F = F.copy()
        F[0] -= direct
    else:
        rest = np.maximum(walk.phi, 0.0)
    Fw = frame_to_world(dom.frame, F)
    fields, targets = (rest, Fw[0], Fw[1], Fw[2]), (phid, flux[0], flux[1], flux[2])
    if direct is not None:
        fields, targets = (direct,) + fields, (outs[2],) + targets
    domain_to_world(fields, dom.frame, dom.origin, dom.h, medium.origin, medium.voxel_size, targets, needed)
    if collimated:
        outs[0][...] = outs[2]
        outs[1][...] = outs[2]


#: Most times the walk's resolution that a sun's unscattered light is computed at on its own
#: domain (:func:`voxel_direct`).
MAX_DIRECT_REFINEMENT = 4


def voxel_direct(light, dom, medium, method, channel: int, needed) -> np.ndarray | None:
    """A sun's unscattered light phi_dir (Eq. 22) on the medium's grid, float32 (nx, ny, nz),
    set where ``needed``, from a domain of its own along the light whose cells are no wider than
    the medium's smallest voxel (at most MAX_DIRECT_REFINEMENT times the walk's resolution):
    Beer-Lambert through the true density there, mapped trilinearly onto the voxel centres
    (docs/METHOD.md, "Unscattered light"). None where the walk's own cells are already that
    fine, where ``method.direct`` is "domain", or where the light keeps no unscattered part
    (an environment's)."""
    h_voxel = float(np.min(medium.voxel_size))
    if method.direct != "voxels" or not getattr(dom, "unscattered", False) or dom.h <= h_voxel * (1 + 1e-9):
        return None
    resolution = min(MAX_DIRECT_REFINEMENT * method.resolution, int(np.ceil(method.resolution * dom.h / h_voxel)))
    fine = directional_domain(medium, light.direction, resolution)
    sigma_t = resample_medium(medium, fine, channel)[0]
    out = np.zeros(medium.shape, np.float32)
    domain_to_world((direct_fluence(sigma_t, fine.h),), fine.frame, fine.origin, fine.h, medium.origin,
                    medium.voxel_size, (out,), needed)
    return out


def transport_direct(solution: Solution) -> np.ndarray | None:
    """float32 (n_lights, n_channels, nx, ny, nz): each light's unscattered fluence as its walk
    saw it, through the medium's capped density (WalkResult.direct_transport, mapped onto the
    voxels as ``Solution.direct`` is), where a domain on a grid kept one, else ``direct``'s; None
    where none did (no voxel capped, or only point lights, whose fields are not on the grid).
    The gathered last bounce scatters it (docs/METHOD.md Eq. 25g)."""
    kept = [ds for ds in solution.domains
            if ds.result.direct_transport is not None and not solution.is_point[ds.light_index]]
    if not kept:
        return None
    med = solution.medium
    needed = seen_voxels(med)
    out = np.array(solution.direct, np.float32)
    for ds in kept:
        dom = ds.domain
        field = np.zeros(med.shape, np.float32)
        domain_to_world((ds.result.direct_transport,), dom.frame, dom.origin, dom.h, med.origin, med.voxel_size,
                        (field,), needed)
        out[ds.light_index, ds.channel][needed] = field[needed]
    return out


def warm_domains(warm, scene) -> tuple[dict, str]:
    """The previous frame's domain solutions a frame may warm-start from, by (light index,
    channel), and why there are none: only when ``warm`` has as many lights (index i is then
    taken to be the same light, moved or not)."""
    if warm is None:
        return {}, ""
    n_prev = len(warm.directions)
    if n_prev != len(scene.lights):
        return {}, f"cold: previous solution has {n_prev} light(s), this scene {len(scene.lights)}"
    return {(ds.light_index, ds.channel): ds for ds in warm.domains}, ""


def voxels_seen(density: np.ndarray) -> np.ndarray:
    """bool (nx, ny, nz): the voxels the renderer can read fields from. It reads them only where
    the density is > 0, by trilinear interpolation, so the voxels within one voxel (26
    neighbours) of a non-empty one; fields elsewhere are left 0."""
    return grow(density > 0)


def seen_voxels(medium) -> np.ndarray:
    """:func:`voxels_seen` of the medium's density, made once per density array and shared by
    propagation and every render of the medium (``Medium.derived``)."""
    return medium.derived("seen", voxels_seen)


def medium_key(medium) -> tuple:
    """What propagation depends on in a medium: grids by identity (a Medium made from another
    with ``dataclasses.replace`` shares them), numbers by value."""
    def value(v):
        return ("grid", id(v)) if np.ndim(v) == 3 else tuple(np.atleast_1d(v).tolist())
    return (id(medium.density), medium.density.shape, tuple(medium.origin), tuple(medium.voxel_size),
            value(medium.scale), value(medium.albedo), value(medium.g))


#: Method fields that only rendering reads: changing them keeps a solution valid.
RENDER_ONLY = ("step", "max_step", "spp", "exposure", "tone", "seed", "gather", "gather_resolution")


def method_key(method) -> tuple:
    return tuple((k, v) for k, v in vars(method).items() if k not in RENDER_ONLY)


def point_fields(domains: list[DomainSolution], n_lights: int, n_channels: int) -> PointFields:
    """Gather the blocks of the lights whose fields the renderer reads in their own domains."""
    pts = PointFields.empty(n_lights, n_channels)
    blocks, total = [], 0
    for ds in domains:
        if not ds.light.fields_in_domain:
            continue
        i, dom = ds.light_index, ds.domain
        blocks.append(dom.render_block(ds.result))
        pts.offset[i, ds.channel] = total
        total += dom.n_cells
        pts.shape[i], pts.params[i], pts.frame[i], pts.full[i] = dom.shape, dom.params, dom.frame, dom.full
    if len(blocks) == 1:                  # render_block's own C-ordered array: no copy
        pts.fields = np.ascontiguousarray(blocks[0])
    elif blocks:
        pts.fields = np.ascontiguousarray(np.concatenate(blocks, axis=1))
    return pts


def solve(scene, progress=None, reuse: Solution | None = None, warm: Solution | None = None) -> Solution:
    """Propagate every light of ``scene`` (and every colour channel of a chromatic medium);
    returns the fields the renderer needs.

    ``warm``: the previous frame's solution of an animation (None: cold, the solve as without
    it, bit for bit). A domain warm-starts when ``warm`` has as many lights and a domain of the
    same light index, channel and kind with a diffusion solve: its diffusion fluence is the
    initial guess of the conjugate-gradient solve (resampled if the grid moved or changed
    shape; the method may differ). The CG stops on the true residual relative to ||b||, so the frame
    is the cold frame within the solver tolerance however different the previous one was (a
    cut costs iterations, not accuracy). The walk always starts cold: it is not a linear fixed
    point (the energy-weighted merge of lobes and the per-packet hand-over make it
    non-additive: walking two halves of the light apart and adding the fields differs from
    walking it together by about ten times what the tolerance leaves, scripts/
    warm_start_study.py), and its packets cannot carry the signed residual a warm start would
    have to propagate. ``stats()["domains"][i]["warm"]`` says whether domain i was
    warm-started, ``"warm_note"`` why not (or that it was resampled).

    ``reuse``: an earlier solution. Lights that it solved for the same medium and method
    (their power may differ: fields are per unit power) are copied from it instead of
    propagated again, so moving one light of several re-propagates that light only, and
    changing a light's power or the camera re-propagates nothing. Grids are compared by
    identity: a medium whose arrays were changed in place must not be solved with ``reuse``.
    ``progress``: optional callable(light index, iteration, residual).
    """
    from .scene import checked_scene
    scene = checked_scene(scene, "solve")
    for name, value in (("reuse", reuse), ("warm", warm)):
        if value is not None and not isinstance(value, Solution):
            raise PopvolError(f"solve: {name} must be an earlier popvol.solve's Solution or None, not "
                              f"{type(value).__name__}")
    if progress is not None and not callable(progress):
        raise PopvolError(f"solve: progress must be a function (light, iteration, residual) or None, not "
                          f"{type(progress).__name__}")
    med = scene.medium.refined(scene.method.voxel_depth)     # the medium itself at voxel_depth 0
    n = len(scene.lights)
    n_ch = med.n_channels
    check_memory(3 * n * n_ch * med.density.size * 4, f"{med.source}: medium", f"fields of {n} "
                 f"light(s) x {n_ch} channel(s) on a {'x'.join(map(str, med.shape))} grid")
    # np.zeros (calloc), not zeros_like (which writes its zeros): the fields are written only
    # where the renderer reads them (voxels_seen), and pages never written (an environment
    # light's direct field) cost nothing
    with small_pages():
        phi, phia, direct = (np.zeros((n, n_ch) + med.shape, np.float32) for _ in range(3))
    diffusion = scene.method.isotropic == "diffusion"
    ordinates = scene.method.solver == "ordinates"
    n_diffuse = n if diffusion or ordinates else 0
    if n_diffuse:
        check_memory(4 * n * n_ch * med.density.size * 4, f"{med.source}: medium",
                     f"diffusion fields of {n} light(s) x {n_ch} channel(s)")
    with small_pages():
        phid = np.zeros((n_diffuse, n_ch) + (med.shape if n_diffuse else (1, 1, 1)), np.float32)
        flux = np.zeros((n_diffuse, n_ch, 3) + (med.shape if n_diffuse else (1, 1, 1)), np.float32)
    lobe_cap = np.full(n, MAX_DIFFUSE_ANISOTROPY)
    key = (medium_key(med), method_key(scene.method))
    old = {}
    if reuse is not None and reuse.key == key:
        old = {(ds.light.key(), ds.channel): ds for ds in reuse.domains}
    prev_domains, cold_note = warm_domains(warm, scene)
    needed = seen_voxels(med)
    transport = med.transport_medium()      # once for every light and channel
    sols = {}
    jobs = []                               # (light index, channel, light, previous domain, why cold)
    for i, light in enumerate(scene.lights):
        for ch in range(n_ch):
            prev = old.get((light.key(), ch))
            if prev is not None:
                j = prev.light_index
                phi[i, ch], phia[i, ch], direct[i, ch] = reuse.phi[j, ch], reuse.phia[j, ch], reuse.direct[j, ch]
                if n_diffuse:
                    phid[i, ch], flux[i, ch] = reuse.phid[j, ch], reuse.flux[j, ch]
                lobe_cap[i] = reuse.lobe_cap[j]
                sols[i, ch] = dataclasses.replace(prev, light=light, light_index=i, reused=True, warm=False,
                                                  warm_note="reused" if warm is not None else "")
                continue
            w, note = None, cold_note
            if warm is not None and not cold_note:
                w = prev_domains.get((i, ch))
                if w is None:
                    note = f"cold: no previous domain of light {i}, channel {ch}"
                elif w.light.type != light.type:
                    w, note = None, f"cold: previous light {i} is a {w.light.type} light"
                elif w.result.diffusion is None:
                    w, note = None, "cold: previous domain has no diffusion solve"
            jobs.append((i, ch, light, w, note))
    domains = [light.domain(med, scene.method) for i, ch, light, w, note in jobs]

    def solve_job(k):
        """Job k: its domain solved and its fields mapped onto the medium's grid (their own
        slices of the fields: jobs run side by side); returns (the solution, its fields' seconds)."""
        i, ch, light, w, note = jobs[k]
        cb = (lambda it, r, i=i: progress(i, it, r)) if progress else None
        ds = solve_light(med, light, scene.method, cb, ch, w, transport, domains[k])
        if warm is not None and w is None:
            ds.warm_note = note
        ds.light_index = i
        t0 = time.perf_counter()
        fine = voxel_direct(light, ds.domain, med, scene.method, ch, needed)
        if ds.result.flux is not None:
            ordinate_fields(ds.result, ds.domain, med, needed, (phi[i, ch], phia[i, ch], direct[i, ch]),
                            phid[i, ch], flux[i, ch])
            if fine is not None:        # the unscattered lobe: phi = phia = phi_dir
                phi[i, ch], phia[i, ch], direct[i, ch] = fine, fine, fine
            lobe_cap[i] = 1.0
            return ds, time.perf_counter() - t0
        if ds.result.scattered is not None:
            # a point light's scattered light, walked on its box (its unscattered light stays in
            # its spherical domain: point_fields)
            ordinate_fields(ds.result.scattered, ds.domain.grid, med, needed, (), phid[i, ch], flux[i, ch])
            lobe_cap[i] = 1.0
            return ds, time.perf_counter() - t0
        d, grid = ds.result.diffusion, ds.diffusion_grid
        diffuse = ()                    # (field, out) pairs of the diffusion stage
        if d is not None:
            J = frame_to_world(grid.frame, d.flux)
            diffuse = tuple(zip((d.phi, J[0], J[1], J[2]), (phid[i, ch], flux[i, ch, 0], flux[i, ch, 1],
                                                             flux[i, ch, 2])))
        if grid is ds.domain and d.h == ds.domain.h and d.phi.shape == tuple(ds.domain.shape):
            # the diffusion stage ran on the walk's own cells: one pass maps both
            ds.domain.world_fields(ds.result, med, needed, (phi[i, ch], phia[i, ch], direct[i, ch]), diffuse)
        else:
            ds.domain.world_fields(ds.result, med, needed, (phi[i, ch], phia[i, ch], direct[i, ch]))
            if diffuse:
                fields, outs = zip(*diffuse)
                domain_to_world(fields, grid.frame, grid.origin, d.h, med.origin, med.voxel_size, outs, needed)
        if fine is not None:            # the scattered rest kept, its unscattered part swapped
            change = fine - direct[i, ch]
            phi[i, ch] += change
            phia[i, ch] += change
            direct[i, ch] = fine
        return ds, time.perf_counter() - t0

    # stage seconds are summed over the domains: solved side by side, they overlap
    seconds = dict.fromkeys(("resample", "propagate", "diffusion", "fields"), 0.0)
    cells = [d.n_cells for d in domains]
    for (i, ch, *_), (ds, fields_seconds) in zip(jobs, run_jobs(solve_job, cells, side_by_side(cells))):
        seconds["fields"] += fields_seconds
        seconds["resample"] += ds.seconds_resample
        seconds["propagate"] += ds.result.seconds
        seconds["diffusion"] += ds.result.seconds_diffusion
        sols[i, ch] = ds
    lights = scene.lights
    sols = [sols[key] for key in sorted(sols)]         # in the order of the lights and channels
    return Solution(medium=med, domains=sols, phi=phi, phia=phia, direct=direct,
                    directions=np.array([l.render_direction for l in lights], np.float64).reshape(-1, 3),
                    positions=np.array([l.render_position for l in lights], np.float64).reshape(-1, 3),
                    is_point=np.array([l.fields_in_domain for l in lights], np.bool_),
                    unscattered=np.array([l.unscattered for l in lights], np.bool_),
                    lobe_a0=broad_lobe_a0(sols, n),
                    irradiance=np.array([l.power for l in lights], np.float64).reshape(-1, 3),
                    points=point_fields(sols, n, n_ch), phid=phid, flux=flux, seconds=seconds, key=key,
                    lobe_cap=lobe_cap)
