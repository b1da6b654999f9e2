"""Render an image of a solved scene by ray marching (see kernels/render.py for the equations)."""
from __future__ import annotations

import dataclasses

import numba
import numpy as np

from . import hg
from .envmap import texel_geometry
from .errors import PopvolError
from .io.images import luminance
from .kernels.gather import emission_lobes, eye_directions, gathered_source
from .kernels.render import EDGE_DEPTH, background_radiance, render_kernel, substeps
from .kernels.sampling import NO_BLOCKS, block_sums, densest_near_blocks, upsample_blocks
from .kernels.source import in_scattering_source
from .pipeline import medium_key, seen_voxels, solve, transport_direct, voxels_seen
from .results import Solution
from .scene import Scene


#: voxels per edge of a block of the coarse grid (empty-space skipping, splitting thick segments):
#: 2^BLOCK_BITS, a power of two, so that the march finds a voxel's block by a shift
BLOCK_BITS = 3
BLOCK = 1 << BLOCK_BITS
#: an empty block of the coarse grid vouches for the blocks up to this many (less one) around it
#: (renderer.skip_blocks), so a ray jumps over up to 2 SKIP_REACH - 1 blocks at once
SKIP_REACH = 16
#: samples nearer the camera than this many (smallest) voxels are lit light by light, not from
#: the combined source: there the view direction turns by more than 1/32 rad across a voxel
NEAR_VOXELS = 32.0
#: combined = None chooses the combined source when pixels x spp x lights lit from the grid is
#: at least the voxels it is built on / COMBINED_VOXELS_PER_SAMPLE: building it costs about
#: one sample's per-light lighting per 8 voxels (measured: WDAS + sun, 640x360: 0.17 s combined
#: against 0.21 s light by light; the viewer's 160x90 drafts of it are faster light by light)
COMBINED_VOXELS_PER_SAMPLE = 8
#: the gather's directions are swept in this many lanes that run in parallel (kernels/gather.py)
GATHER_LANES = 4
#: the gather's blocks are at most this many mean free paths wide where the medium is dense
#: (its 90th percentile of sigma_t): the front-lit slab at 0.25-1 mean free paths per voxel
#: moved by 2-10 % with blocks of 2^3 voxels (tests/test_gather.py)
GATHER_BLOCK_MFP = 0.5
#: the cap of denser gather directions reaches this far (radians) beyond the view's half-diagonal
GATHER_CAP_MARGIN = np.radians(15.0)
#: the medium bundle's occupied cells left out (occupied_cells): the march interpolates the
#: density everywhere (render_inputs with skip=False; the gather's cropped and coarse grids,
#: which it does not march)
NO_CELLS = np.zeros((0, 0, 0), np.uint8)
#: voxels to spare around the box the gather transports light in
GATHER_MARGIN = 2


def render(scene: Scene, solution: Solution | None = None, jitter: bool | None = None,
           combined: bool | None = None, skip: bool = True) -> np.ndarray:
    """Linear HDR image float32 (height, width, 3) of ``scene``.

    ``solution`` is the output of :func:`popvol.solve`; if omitted the scene is solved first.
    Moving only the camera does not need a new solution. ``jitter``: hashed sub-pixel and
    along-ray offsets per sample, else one sample at the pixel centre and the march segments'
    midpoints (None: jitter when ``method.spp`` > 1; docs/METHOD.md, Eq. 25). ``combined``:
    light the samples from one in-scattering source built for this view (kernels/source.py), else light by light
    (None: whichever costs less, by COMBINED_VOXELS_PER_SAMPLE; the images differ by relMSE
    <= 1e-4, docs/METHOD.md); ``skip``: march only within the box of the medium's non-empty
    blocks, jump over empty blocks and do not interpolate the density in cells whose eight
    voxels are empty (the image is bitwise the same).
    With ``method.gather`` > 0 the combined source is always used (it holds the gathered light),
    except for a solution of the unscattered light alone (``Solution.single_scattering()``),
    which is rendered as it is, and where no light has an unscattered part (an environment
    alone), which is lit from the lobes.
    """
    from .scene import checked_scene
    scene = checked_scene(scene, "render")
    if solution is None:
        solution = solve(scene)
    cam = scene.camera
    out = np.zeros((cam.height, cam.width, 3), np.float32)
    inputs = render_inputs(scene, solution, jitter, combined, skip)
    render_kernel(*inputs, out, numba.get_num_threads())
    if not np.all(np.isfinite(out)):
        raise PopvolError("internal error: the rendered image has non-finite pixels; please report it "
                          f"with the scene ({scene.source})")
    return out


def solved_for_another(scene: Scene, med, solution: Solution) -> str:
    """What ``solution`` was solved for that ``scene`` (its medium at the method's voxel depth,
    ``med``) does not have, in a message's words, or "" where it serves the scene: the same
    medium (the density, the same array or equal values; its box and optics) and the same
    lights in the same order (their kind and where their light comes from: Light.key(); the
    image takes their power from the solution: Solution.relit gives it other powers). The method may differ: a solution made at another resolution lights the
    same grid (the viewer's drafts render with the full solution)."""
    solved = solution.medium
    same = lambda a, b: a is b or (np.shape(a) == np.shape(b) and np.array_equal(a, b))
    if solution.phi.shape[1] != med.n_channels:
        return f"a {'grey' if solution.phi.shape[1] == 1 else 'chromatic'} medium"
    if not (same(solved.density, med.density) and same(solved.origin, med.origin)
            and same(solved.voxel_size, med.voxel_size) and same(solved.scale, med.scale)
            and same(solved.albedo, med.albedo) and same(solved.g, med.g)):
        return "another medium (its density, box or optics differ)"
    lights = {ds.light_index: ds.light.key() for ds in solution.domains}
    if solution.phi.shape[0] != len(scene.lights) or any(
            lights.get(i, light.key()) != light.key() for i, light in enumerate(scene.lights)):
        return f"other lights ({solution.phi.shape[0]} of them, or another kind, direction or position)"
    return ""


def render_inputs(scene: Scene, solution: Solution, jitter: bool | None = None, combined: bool | None = None,
                  skip: bool = True) -> tuple:
    """The render kernel's inputs but the image, packed as it takes them (kernels/render.py):
    (medium, lights, grid, spherical, view, camera, march, background). The one place that
    packs the scene and the solution's fields for the kernel; with ``combined`` it builds the
    view's combined in-scattering source (so its cost is part of rendering); ``skip``: the march
    skips what is empty (:func:`render`), else it takes every sample (the medium's occupied
    cells are then left out: NO_CELLS)."""
    m = scene.method
    med = scene.medium.refined(m.voxel_depth)     # the grid the solution's fields are on
    if not isinstance(solution, Solution):
        raise PopvolError(f"render: solution must be what popvol.solve returns, not {type(solution).__name__}")
    if solution.phi.shape[2:] != med.shape:
        raise PopvolError(f"{scene.source}: the solution's fields are on a {'x'.join(map(str, solution.phi.shape[2:]))} "
                          f"grid, the medium at method.voxel_depth = {m.voxel_depth:g} on "
                          f"{'x'.join(map(str, med.shape))}; solve the scene again")
    other = solved_for_another(scene, med, solution)
    if other:
        raise PopvolError(f"{scene.source}: the solution was solved for {other}; solve the scene again (a "
                          "solution serves another camera, not another medium or other lights)")
    cam = scene.camera
    lo, hi = med.bounds
    # grey per-voxel albedo, or an RGB constant as a (1, 1, 1) grid of 1 times albedo_rgb
    albedo, albedo_rgb = ((med.albedo, np.ones(3)) if med.albedo_per_voxel
                          else (np.ones((1, 1, 1), np.float32), np.asarray(med.albedo, np.float64)))
    seen = seen_voxels(med)
    blocks = med.derived("skip_blocks", lambda density: skip_blocks(densest_in_blocks(density, BLOCK)))
    medium = (med.density, np.asarray(med.scale, np.float64), albedo, albedo_rgb, med.g_grid(),
              med.origin, med.voxel_size, lo, hi, blocks, BLOCK_BITS,
              med.derived("occupied_cells", occupied_cells) if skip else NO_CELLS)
    camera = (cam.origin, cam.basis(), float(np.tan(np.radians(cam.fov) / 2)), int(cam.width),
              int(cam.height))
    gather_on = m.gather > 0 and not solution.single
    environment, regions, patterns = (gathered_environment(scene, solution) if gather_on
                                      else (None, np.zeros(len(solution.unscattered), bool), None))
    gathering = gather_on and bool((solution.unscattered | regions).any())
    # the regions whose unscattered lobe the gather emits with their pattern (Eq. 26a): where the
    # walk kept it apart and g is one number (the pattern is tabulated for it)
    lobe_a0 = np.zeros(len(solution.unscattered))
    if gathering and patterns is not None and solution.lobe_a0 is not None and med.g_grid().size == 1:
        lobe_a0 = np.where(regions, solution.lobe_a0, 0.0)
    lights = (solution.is_point, np.ascontiguousarray(solution.directions, np.float64),
              np.ascontiguousarray(solution.irradiance, np.float64),
              np.ascontiguousarray(solution.positions, np.float64), np.asarray(solution.unscattered, np.bool_),
              np.ascontiguousarray(lobe_a0, np.float64))
    if gathering:
        # the scattered light toward the camera gathered on the grid from the lights with an
        # unscattered part and the regions of an environment map, whose first scattering is the
        # map's light entering through the grid's faces; the samples add the single scattering of
        # the first and all the light of the others (a map's sun), whose first scattering the
        # gather cannot make (docs/METHOD.md, "Gathered last bounce")
        own = solution.unscattered | regions
        grid, spherical = field_bundles(gathered_fields(solution))
        eye = np.asarray(cam.origin, np.float64)
        # the gather is light transport: it sees the capped density, as the walk did
        transport = med.transport_medium()
        factor = gather_factor(transport, m.gather_resolution)
        args = ((transport.density,) + medium[1:], *only_lights(own, lights, grid, spherical), seen, factor,
                environment is not None)
        # made once per fields, medium and lights and kept with the solution (Solution.cache):
        # a camera move gathers again from it
        fields = grid[:5] + spherical[:1]
        key = ("gather", factor, medium_key(transport), tuple(map(id, fields)), own.tobytes(), lights[2].tobytes(),
               lights[5].tobytes())
        kept = solution.cache.get("gather")
        if kept is None or kept[0] != key:
            # holding the medium and the fields keeps the ids in the key theirs
            kept = (key, (transport, fields), gather_state(*args))
            solution.cache["gather"] = kept
        kept_patterns = None if patterns is None else [patterns[i] for i in np.flatnonzero(own)]
        gathered = gather(*args[:3], eye, seen, m.gather, factor, gather_cap(cam), state=kept[2],
                          environment=environment, patterns=kept_patterns)
        if not own.all():                 # the others' light, all of it, from their lobes
            others, (others_grid, others_spherical) = only_lights(~own, lights, grid, spherical)
            in_scattering_source(medium, others, others_grid, others_spherical, eye, seen, gathered,
                                 numba.get_num_threads())
        solution = solution.single_scattering()
        combined = True
    grid, spherical = field_bundles(solution)
    source = np.zeros((0, 0, 0, 3), np.float32)
    grid_lit = int((~solution.is_point).sum()) + (len(solution.is_point) if solution.phid.shape[0] > 0 else 0)
    if combined is None:
        samples = cam.width * cam.height * m.spp * grid_lit
        combined = samples * COMBINED_VOXELS_PER_SAMPLE >= med.derived("seen_count", lambda _: int(seen.sum()))
    if gathering:
        source = gathered                 # every sample reads the gathered light from the grid
    elif combined and grid_lit > 0:
        source = np.zeros(med.density.shape + (3,), np.float32)
    if combined and grid_lit > 0:         # the single scattering (gathering), or all of it
        # gathering, only the lights with an unscattered part have a single scattering (the
        # others' fields are 0 in Solution.single_scattering)
        lit, (lit_grid, lit_spherical) = (only_lights(solution.unscattered, lights, grid, spherical) if gathering
                                          else (lights, (grid, spherical)))
        in_scattering_source(medium, lit, lit_grid, lit_spherical, np.asarray(cam.origin, np.float64),
                             seen, source, numba.get_num_threads())
    near = 0.0 if gathering else float(NEAR_VOXELS * med.voxel_size.min())
    view = (source, near, np.flatnonzero(solution.is_point).astype(np.int64))
    step = float(m.step * med.voxel_size.min())
    # whether any block is dense enough that the march splits its segments (the kernel's own rule)
    dense = bool(blocks.size) and substeps(medium, float(blocks.max()), step) > 1
    if jitter is None:                    # one sample: the pixel centre is closer to the pixel's mean
        jitter = m.spp > 1
    march = (step, int(m.spp), int(m.seed), bool(jitter), bool(skip), dense, int(m.max_step), thick_faces(med),
             dense_blocks_box(med, blocks))
    return medium, lights, grid, spherical, view, camera, march, background_map(scene)


def dense_blocks_box(medium, blocks: np.ndarray) -> np.ndarray:
    """float64 (2, 3): the world box (lo, hi) of the non-empty blocks (value >= 0) of the
    march's coarse grid ``blocks`` (:func:`skip_blocks`), grown by a thousandth of a voxel so
    that a point outside it is outside by more than rounding: every point of the medium's box
    outside it lies in an empty block, where the density is 0. Where a block on the grid's edge
    is non-empty the box reaches the medium's box there, as the blocks' clamped index does
    (block b holds the voxel index (x - origin) / voxel in [b BLOCK, (b + 1) BLOCK)). An empty
    box (lo > hi) where every block is empty."""
    non_empty = blocks >= 0
    if not non_empty.any():
        return np.array([[1.0] * 3, [0.0] * 3])
    box = np.array(medium.bounds, np.float64)
    h = np.asarray(medium.voxel_size, np.float64)
    for a, s in enumerate(occupied_box(non_empty, 0)):
        if s.start > 0:
            box[0, a] = medium.origin[a] + s.start * BLOCK * h[a] - 1e-3 * h[a]
        if s.stop < blocks.shape[a]:
            box[1, a] = medium.origin[a] + s.stop * BLOCK * h[a] + 1e-3 * h[a]
    return box


def thick_faces(medium) -> bool:
    """Whether some voxel on the grid's faces is at least kernels.render.EDGE_DEPTH mean free
    paths thick across that face (the densest channel's sigma_t times the voxel's side along
    the face's normal): then the march takes the suns' single scattering in the grid's outer
    half cell by Beer-Lambert (kernels.render.edge_single_scattering, docs/METHOD.md Eq. 25d)."""
    densest = medium.derived("densest on the faces", lambda rho: [
        float(np.take(rho, [0, rho.shape[a] - 1], axis=a).max()) for a in range(3)])
    sigma = float(np.max(medium.scale))
    return any(densest[a] * sigma * float(medium.voxel_size[a]) >= EDGE_DEPTH for a in range(3))


def field_bundles(solution: Solution) -> tuple[tuple, tuple]:
    """The solution's fields as the kernels take them: (grid, spherical) (kernels/render.py)."""
    grid = (solution.phi, solution.phia, solution.direct, solution.phid, solution.flux,
            np.ascontiguousarray(solution.lobe_cap, np.float64))
    pts = solution.points
    return grid, (pts.fields, pts.offset, pts.shape, pts.params, pts.frame, pts.full)


def gathered_fields(solution: Solution) -> Solution:
    """The solution as the gathered last bounce reads it: where the walk solved a capped medium,
    each sun's unscattered light through the capped density it walked (pipeline.transport_direct)
    in place of the true one, the scattered rest kept (phi - direct + direct', the same for phi a:
    the unscattered lobe has a = 1; docs/METHOD.md Eq. 25g). The camera's own samples keep the
    true one. Made once per fields and kept with the solution (Solution.cache); the solution
    itself where nothing was capped."""
    key = ("transport_direct", id(solution.phi), id(solution.phia), id(solution.direct))
    kept = solution.cache.get("transport_direct")
    if kept is None or kept[0] != key:
        capped = transport_direct(solution)
        if capped is None:
            return solution
        change = capped - solution.direct
        # holding the fields keeps the ids in the key theirs
        kept = (key, (solution.phi, solution.phia, solution.direct),
                (solution.phi + change, solution.phia + change, capped))
        solution.cache["transport_direct"] = kept
    phi, phia, direct = kept[2]
    return dataclasses.replace(solution, phi=phi, phia=phia, direct=direct)


def only_lights(keep: np.ndarray, lights: tuple, grid: tuple, spherical: tuple) -> tuple[tuple, tuple]:
    """The kernels' lights bundle and (grid, spherical) bundles of the lights where ``keep``
    (bool (n_lights,)): each per-light array's rows (the diffusion fields' only if there are
    any; the point lights' flat field array as it is, its offsets picked); views, not copies,
    where the lights kept are consecutive (a sun before a sky's lights, or the sky after it)."""
    phi, phia, direct, phid, flux, lobe_cap = grid
    fields, offset, shape, params, frame, full = spherical
    if keep.all():
        return lights, (grid, spherical)
    kept = np.flatnonzero(keep)
    if len(kept) and kept[-1] - kept[0] == len(kept) - 1:
        keep = slice(kept[0], kept[-1] + 1)
    rows = (lambda a: a[keep] if a.shape[0] else a)
    return (tuple(a[keep] for a in lights),
            ((phi[keep], phia[keep], direct[keep], rows(phid), rows(flux), lobe_cap[keep]),
             (fields, offset[keep], shape[keep], params[keep], frame[keep], full[keep])))


def gather_directions(n: int, axis=None, cap: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """n unit directions (float64 (n, 3)) and their weights (solid angles, summing to 4 pi).

    Without ``axis``: a Fibonacci sphere, equal weights 4 pi / n. With ``axis`` (a unit vector)
    and ``cap`` (radians, in (0, pi)): n // 2 directions on a Fibonacci spiral of the cap of
    half-angle ``cap`` about ``axis`` and the rest on the rest of the sphere, each weighted by
    its part's solid angle over its count: denser where the phase function toward the camera
    peaks (renderer.gather_cap)."""
    def spiral(m, z_hi, z_lo):           # m points uniform in z in [z_lo, z_hi], about +z
        i = np.arange(m) + 0.5
        z = z_hi - (z_hi - z_lo) * i / m
        azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
        r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
        return np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], 1)
    if axis is None or not 0.0 < cap < np.pi or n < 2:
        return spiral(n, 1.0, -1.0), np.full(n, 4.0 * np.pi / n)
    c = np.cos(cap)
    n_cap = n // 2
    dirs = np.concatenate([spiral(n_cap, 1.0, c), spiral(n - n_cap, c, -1.0)])
    weights = np.concatenate([np.full(n_cap, 2 * np.pi * (1 - c) / n_cap),
                              np.full(n - n_cap, 2 * np.pi * (1 + c) / (n - n_cap))])
    z = np.asarray(axis, np.float64) / np.linalg.norm(axis)        # rotate +z onto axis
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return dirs @ np.stack([x, y, z]), weights


def gather_cap(camera) -> tuple[np.ndarray, float]:
    """The axis and half-angle of the cap where gather_directions puts half its directions: about
    the direction from the scene toward the camera, wide enough for every pixel's view direction
    (the half-diagonal of the field of view) plus GATHER_CAP_MARGIN for the phase function's peak."""
    tan_half = np.tan(np.radians(camera.fov) / 2)
    half_diagonal = np.arctan(tan_half * np.hypot(1.0, camera.width / camera.height))
    return -camera.basis()[0], float(min(half_diagonal + GATHER_CAP_MARGIN, np.radians(120.0)))


def gathered_environment(scene, solution) -> tuple[np.ndarray | None, np.ndarray, list | None]:
    """(the environment map whose light the gather lets in through the grid's faces, float32
    (H, 2H, 3); bool (n_lights,), the lights it stands for: the map's median-cut regions,
    ``DirectionalLight.map_region``, not its sun; per light, its region's pattern
    (:func:`region_pattern`) or None). Each region's texels are scaled by its
    light's power in the solution over the power the scene gives it (1 but where the solution
    was relit). (None, all False, None) where the scene has no such light, or the solution is not
    of the scene's lights. The map is made once per map and powers and kept with the solution
    (``Solution.cache``), so that a camera move does not make it again."""
    n = len(solution.unscattered)
    regions = np.array([getattr(light, "map_region", False) for light in scene.lights], bool)
    if scene.environment is None or not regions.any() or len(regions) != n:
        return None, np.zeros(n, bool), None
    env = scene.environment.radiance
    scales = []
    for i in np.flatnonzero(regions):
        own = np.asarray(scene.lights[i].power, np.float64)
        scales.append(np.divide(solution.irradiance[i], own, out=np.zeros(3), where=own > 0))
    key = ("environment", id(env), tuple(map(id, (scene.lights[i].texels for i in np.flatnonzero(regions)))),
           np.asarray(scales).tobytes())
    kept = solution.cache.get("environment")
    if kept is None or kept[0] != key:
        out = np.zeros(env.shape, np.float32)
        for i, scale in zip(np.flatnonzero(regions), scales):
            texels = scene.lights[i].texels
            out[texels] += (env[texels] * scale).astype(np.float32)
        patterns = [region_pattern(env, light.texels) if region else None
                    for light, region in zip(scene.lights, regions)]
        # holding the map and the texels keeps the ids in the key theirs
        kept = (key, (env, [scene.lights[i].texels for i in np.flatnonzero(regions)]), (out, patterns))
        solution.cache["environment"] = kept
    return kept[2][0], regions, kept[2][1]


#: a region's pattern (:func:`region_pattern`) takes the map in blocks of texels, at most this
#: many texels tall (a sky of 64 rows texel by texel)
PATTERN_ROWS = 64


def region_pattern(env: np.ndarray, texels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The angular pattern of an environment region's light (docs/METHOD.md Eq. 26a): (omega
    float64 (T, 3), the directions its light travels, -w for the directions w toward the sky;
    p float64 (T,), their shares of its luminance lum(L) dOmega, summing to 1), from ``env``
    float32 (H, W, 3) at the region's ``texels`` bool (H, W), in blocks of b x b texels (b =
    ceil(H / PATTERN_ROWS)), each as its luminance-weighted mean direction."""
    H, W = env.shape[:2]
    d, omega = texel_geometry(H, W)
    lum = luminance(env.astype(np.float64)) * omega * texels
    b = -(-H // PATTERN_ROWS)
    if b > 1:                   # zero-weight texels pad the map to whole blocks
        pad = ((0, -H % b), (0, -W % b))
        lum = np.pad(lum, pad)
        m = np.pad(d, pad + ((0, 0),)) * lum[..., None]
        h, w = lum.shape[0] // b, lum.shape[1] // b
        m = m.reshape(h, b, w, b, 3).sum(axis=(1, 3)).reshape(-1, 3)
        lum = lum.reshape(h, b, w, b).sum(axis=(1, 3)).ravel()
    else:
        m, lum = d.reshape(-1, 3), lum.ravel()
    keep = lum > 0
    dirs = m[keep] / np.linalg.norm(m[keep], axis=1)[:, None]
    p = lum[keep]
    # a region holds some light (envmap.decompose makes none of dark texels)
    return -dirs, p / p.sum()


def pattern_table(patterns, dirs: np.ndarray, g: float) -> np.ndarray:
    """float64 (N, n_lights): for each gather direction w_i (``dirs`` float64 (N, 3)) and light
    l, what a unit fluence of its region's unscattered light scatters toward w_i, per
    steradian (docs/METHOD.md Eq. 26a): sum_t p_t f_hg(omega_t . w_i; g) over its pattern
    (:func:`region_pattern`; ``patterns`` one per light, None for a light without one: 0 there,
    or ``patterns`` None: no column read)."""
    out = np.zeros((len(dirs), max(len(patterns or ()), 1)))
    for l, pattern in enumerate(patterns or ()):
        if pattern is not None:
            omega, p = pattern
            for t in range(0, len(p), 4096):         # in chunks: little memory
                o = omega[t:t + 4096]
                # by elementwise products, not BLAS (domains.frame_to_world says why)
                mu = dirs[:, 0, None] * o[:, 0] + dirs[:, 1, None] * o[:, 1] + dirs[:, 2, None] * o[:, 2]
                out[:, l] += (hg.f_hg(np.clip(mu, -1.0, 1.0), g) * p[t:t + 4096]).sum(axis=1)
    return out


def gather(medium, lights, bundles, eye, seen, n_directions: int, factor: int = 1, cap=None,
           state: tuple | None = None, environment=None, patterns=None) -> np.ndarray:
    """float32 (nx, ny, nz, 3): the scattered light gathered toward the camera at ``eye`` from
    ``n_directions`` directions (kernels/gather.py), where ``seen``; 0 elsewhere.

    The light is transported within the box of the voxels that hold density or are seen, with
    GATHER_MARGIN voxels to spare (outside it there is nothing to emit, and light that leaves a
    box never comes back). With ``factor`` > 1 it is transported on a grid of blocks of
    factor^3 voxels of that box (the medium and the fields averaged over each block's voxels) and
    read back at the voxels by trilinear interpolation between the blocks' centres (clamped to
    the edge), so the sweeps cost about factor^-3 as much. ``cap``: (axis, half-angle) of
    gather_directions' cap, or None for directions on the whole sphere. ``state``: what
    :func:`gather_state` makes of the same medium, lights, bundles, seen and factor, if the
    caller kept it (it does not depend on the camera). ``environment``: the map whose light
    enters the grid (:func:`gathered_environment`), float32 (H, 2H, 3), or None: nothing
    enters; the radiance arriving along a direction w is the map's from -w. ``patterns``: per
    light of ``lights``, its region's pattern (:func:`region_pattern`) or None, for the lights
    whose unscattered lobe is gathered with it (``lights``' lobe_a0 > 0; None: no such light)."""
    box, seen_box, medium, grids, across_z, lobes, colour, sun = state or gather_state(
        medium, lights, bundles, seen, factor, environment is not None)
    needed = grids[4]
    dirs, weights = gather_directions(n_directions, *(cap or (None, 0.0)))
    boundary = np.zeros((len(dirs), 1 if colour is not None else 3))
    if environment is not None:                 # the radiance arriving along w comes from -w
        boundary[:] = [background_radiance(environment, -w) for w in dirs]
    lanes = min(GATHER_LANES, n_directions)
    out = np.zeros((lanes,) + needed.shape + (1 if colour is not None else 3,), np.float32)
    norm = np.zeros((lanes,) + needed.shape, np.float32)
    # the sun's lobe's own sums (kernels.gather.gathered_source), placeholders where it has none
    apart = bool(sun[0].any())
    apart_shape = needed.shape if apart else (1, 1, 1)
    out_sun = np.zeros((lanes,) + apart_shape + out.shape[4:], np.float32)
    norm_sun = np.zeros((lanes,) + apart_shape, np.float32)
    to_eye = eye_directions(medium, eye, needed)
    if patterns is None and np.any(lights[5] > 0):
        raise ValueError("gather: lights with a region's pattern (lobe_a0 > 0) need their patterns")
    pattern = pattern_table(patterns, dirs, float(medium[4].flat[0]))
    gathered_source(medium, lobes, grids + (to_eye,), across_z + (z_first(to_eye),), dirs, weights, out, norm,
                    boundary, sun, out_sun, norm_sun, pattern)
    norm = norm.sum(axis=0, dtype=np.float64)
    light = out.sum(axis=0, dtype=np.float64) / np.where(norm > 0, norm, 1.0)[..., None]
    if apart:
        # the sun's unscattered lobe and the phase toward the eye integrated exactly (Eq. 25e):
        # the quadrature averages only the transported light, weighted by their product
        norm_sun = norm_sun.sum(axis=0, dtype=np.float64)
        mean = out_sun.sum(axis=0, dtype=np.float64) / np.where(norm_sun > 0, norm_sun, 1.0)[..., None]
        light += mean * hg.f_hg(to_eye @ sun[1], float(medium[4].flat[0]) * sun[2])[..., None]
    light = (light * colour if colour is not None else light).astype(np.float32)
    if factor > 1:
        light = upsample(light, factor, seen_box)
    else:
        light[~seen_box] = 0.0
    if light.shape[:3] == seen.shape:
        return light
    full = np.zeros(seen.shape + (3,), np.float32)
    full[box] = light
    return full


def gather_state(medium, lights, bundles, seen, factor: int = 1, environment: bool = False) -> tuple:
    """What :func:`gather` transports, made before the camera is known: (the box, the seen
    voxels in it, the medium bundle of the transport grid, its grids (density, albedo, g, the
    lobes' row of each cell (int64, -1 where empty), the cells that are read back) and the same
    z first (:func:`z_first`), as kernels.gather.gathered_source takes them but the eye's, the
    lobes (kernels.gather.emission_lobes), the one colour of the light or None:
    :func:`one_colour`, always None with an ``environment`` entering the grid, whose light has
    colours of its own), and which lobes are gathered apart (:func:`separated_sun`)."""
    grid, spherical = bundles
    box = occupied_box((medium[0] > 0) | seen, GATHER_MARGIN)
    medium, grid = crop_bundles(medium, grid, box)
    # a copy, not a view: a view of a sub-box has Numba's 'A' layout and a view of the whole grid
    # 'C', and every kernel that takes it would be compiled once for each (about 12 s more)
    seen_box = np.ascontiguousarray(seen[box])
    if factor > 1:
        medium, grid, needed = coarse_bundles(medium, grid, seen_box, factor)
    else:
        needed = seen_box
    density = medium[0]
    cells = np.argwhere(density > 0)
    slot = np.full(density.shape, -1, np.int64)
    slot[tuple(cells.T)] = np.arange(len(cells))
    # one light in a grey medium emits one colour: transport one channel, times the colour
    colour = None if environment else one_colour(medium, lights, grid)
    if colour is not None:
        lights = lights[:2] + (np.ones_like(lights[2]),) + lights[3:]
    lobes = np.zeros((len(cells), 3 * len(lights[0]) * grid[0].shape[1], 7), np.float32)
    emission_lobes(medium, lights, grid, spherical, cells, lobes)
    sun = separated_sun(medium, lights, lobes)
    # the lobes that hold light somewhere (a light's kinds of lobe that are empty everywhere, as
    # the direct lobe of an environment's lights, cost every cell a test in every sweep)
    lit = np.any(lobes[:, :, 4:] != 0, axis=(0, 2))
    lobes = np.ascontiguousarray(lobes[:, lit])
    sun = (np.ascontiguousarray(sun[0][lit]),) + sun[1:]
    grids = (density, medium[2], medium[4], slot, needed)
    return box, seen_box, medium, grids, tuple(map(z_first, grids)), lobes, colour, sun


def separated_sun(medium, lights, lobes) -> tuple[np.ndarray, np.ndarray, float]:
    """Which lobes the gather transports apart (kernels.gather.gathered_source's ``sun``):
    (separated bool (K,), axis float64 (3,), g_sun): the unscattered light of the directional
    light whose unscattered lobes (kernels.gather.emission_lobes, kind 0: one per field channel)
    carry the most power, a lobe f_hg(axis . w; g_sun) about its direction the same in every
    cell, so its angular factor can be integrated with the phase toward the eye exactly
    (docs/METHOD.md, "Gathered last bounce", Eq. 25e). None is separated (all False) where g
    varies from voxel to voxel (by more than 1e-6 of itself), or no directional light has
    unscattered light."""
    separated = np.zeros(lobes.shape[1], np.bool_)
    none = (separated, np.array([0.0, 0.0, 1.0]), 0.0)
    g = medium[4]
    if g.size == 0 or np.ptp(g) > 1e-6 * abs(float(g.flat[0])) or lobes.shape[0] == 0 or len(lights[0]) == 0:
        return none
    n_ch = lobes.shape[1] // (3 * len(lights[0]))
    best, best_power = None, 0.0
    for l in range(len(lights[0])):
        if lights[0][l] or not lights[4][l]:        # a point light's axis turns from cell to cell;
            continue                                # an environment's light has no delta lobe
        kinds = [3 * (l * n_ch + c) for c in range(n_ch)]
        power = float(np.sum(lobes[:, kinds, 4:], dtype=np.float64))
        if power > best_power:
            best, best_power = kinds, power
    if best is None:
        return none
    separated[best] = True
    # the axis and g of one lobe that holds light (every one of them has the same)
    row, j = np.argwhere(np.any(lobes[:, best, 4:] != 0, axis=2))[0]
    return separated, lobes[row, best[j], :3].astype(np.float64), float(lobes[row, best[j], 3])


def z_first(x: np.ndarray) -> np.ndarray:
    """A C-ordered copy of x (nx, ny, nz, ...) with its axes as (nz, nx, ny, ...)."""
    return np.ascontiguousarray(np.moveaxis(x, 2, 0))


def one_colour(medium, lights, grid) -> np.ndarray | None:
    """The RGB colour (float64 (3,)) of all the light a medium lit by ``lights`` scatters, where
    it has one: a single light, grey fields and a grey medium (sigma_t and albedo alike in R, G
    and B); None otherwise."""
    scale, albedo_rgb = medium[1], medium[3]
    if (len(lights[0]) == 1 and grid[0].shape[1] == 1 and np.all(scale == scale[0])
            and np.all(albedo_rgb == albedo_rgb[0])):
        return np.asarray(lights[2][0], np.float64)
    return None


def occupied_box(mask: np.ndarray, margin: int) -> tuple[slice, slice, slice]:
    """The index box of ``mask``'s true voxels (bool (nx, ny, nz)), ``margin`` voxels wider on
    every side within the grid (a one-voxel box where none is true)."""
    box = []
    for axis in range(3):
        hit = np.flatnonzero(mask.any(axis=tuple(a for a in range(3) if a != axis)))
        if hit.size == 0:
            return (slice(0, 1),) * 3
        box.append(slice(int(max(hit[0] - margin, 0)), int(min(hit[-1] + 1 + margin, mask.shape[axis]))))
    return tuple(box)


def crop_bundles(medium, grid, box) -> tuple[tuple, tuple]:
    """The render kernel's medium and grid bundles cut to the index ``box`` (constants stay
    constants; the origin moves to the box's first voxel)."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    phi, phia, direct, phid, flux, lobe_cap = grid
    whole = all(b.stop - b.start == n for b, n in zip(box, density.shape))
    cut = (lambda a: a if a.size <= 1 or whole else np.ascontiguousarray(a[(Ellipsis,) + box]))
    start = np.array([b.start for b in box], np.float64)
    return ((cut(density), scale, cut(albedo), albedo_rgb, cut(g_grid), origin + start * voxel, voxel, lo, hi,
             blocks, block_bits, NO_CELLS), tuple(cut(f) for f in (phi, phia, direct, phid, flux)) + (lobe_cap,))


def gather_factor(medium, resolution: int) -> int:
    """The gather grid's blocks are factor^3 voxels of ``medium`` (a Medium): the fewest with at
    most ``resolution`` blocks along the grid's longest side, but no block wider than
    GATHER_BLOCK_MFP mean free paths where the medium is dense (sigma_t at the 90th percentile
    of the non-empty voxels); 1 (the voxels themselves) for resolution 0."""
    if not resolution:
        return 1
    factor = -(-max(medium.shape) // resolution)
    # made once per density array (Medium.derived): every frame of a still medium asks again
    rho_90 = medium.derived("90th percentile of the non-empty density", lambda density: (
        float(np.percentile(density[density > 0], 90)) if (density > 0).any() else None))
    if rho_90 is not None:
        mfp_per_voxel = rho_90 * float(np.max(medium.scale)) * float(medium.voxel_size.max())
        factor = min(factor, int(GATHER_BLOCK_MFP / max(mfp_per_voxel, 1e-30)))
    return max(1, factor)


def block_mean(x: np.ndarray, factor: int, only: np.ndarray | None = None) -> np.ndarray:
    """float32: the mean of x (..., nx, ny, nz) over blocks of factor^3 voxels along its last
    three axes (the blocks at the far edges over the voxels they hold; kernels/sampling.py).
    ``only`` (bool, the blocks' shape): the blocks made (0 elsewhere), of which x is read only
    along the rows of voxels that cross them; None: all."""
    n = x.shape[-3:]
    flat = np.ascontiguousarray(x, np.float32).reshape((-1,) + n)
    out = np.empty((flat.shape[0],) + tuple(-(-s // factor) for s in n), np.float32)
    block_sums(flat, factor, True, out, NO_BLOCKS if only is None else np.ascontiguousarray(only, np.uint8))
    return out.reshape(x.shape[:-3] + out.shape[1:])


def coarse_bundles(medium, grid, seen, factor: int) -> tuple[tuple, tuple, np.ndarray]:
    """The render kernel's medium and grid bundles on blocks of factor^3 voxels (block means;
    constants stay constants; the origin is the first block's centre; the fields 0 on the
    blocks without medium), and the blocks the upsampling reads: those holding a seen voxel and
    their neighbours."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    phi, phia, direct, phid, flux, lobe_cap = grid
    const = (lambda a: a if a.size == 1 else block_mean(a, factor))
    coarse_density = block_mean(density, factor)
    coarse_medium = (coarse_density, scale, const(albedo), albedo_rgb, const(g_grid),
                     origin + 0.5 * (factor - 1) * voxel, voxel * factor, lo, hi, blocks, block_bits, NO_CELLS)
    # the fields only on the blocks that hold medium, the cells whose lobes the gather emits
    # (the fields elsewhere are mostly pages never written, whose first read costs a page fault)
    holding = coarse_density > 0
    coarse_grid = tuple(block_mean(f, factor, holding) if f.size > 1 else f
                        for f in (phi, phia, direct, phid, flux)) + (lobe_cap,)
    # the blocks holding a seen voxel and their 26 neighbours (the trilinear stencil): the same
    # one-block dilation voxels_seen makes of a density
    needed = voxels_seen(block_mean(seen.astype(np.float32), factor))
    return coarse_medium, coarse_grid, needed


def upsample(coarse: np.ndarray, factor: int, needed: np.ndarray) -> np.ndarray:
    """float32 (nx, ny, nz, C): from the blocks' values ``coarse`` (bx, by, bz, C) at their
    centres, the trilinear value at the centres of the voxels where ``needed`` (bool (nx, ny,
    nz)), clamped to the edge; 0 elsewhere (kernels/sampling.py)."""
    out = np.zeros(needed.shape + coarse.shape[3:], np.float32)
    upsample_blocks(np.ascontiguousarray(coarse, np.float32), factor, needed, out)
    return out


def densest_in_blocks(density: np.ndarray, block: int) -> np.ndarray:
    """float32 (ceil(nx / block), ...): the largest density within one voxel of block b (voxels
    [block b - 1, block (b + 1) + 1] along each axis, within the grid). Where it is 0, the density's
    trilinear value is 0 at every point whose clamped cell index lies in the block, with a voxel
    to spare (the stencil of such a point reads voxels [block b, block (b + 1)] only), so the
    march skips the block; elsewhere it bounds the density at every such point, and the march
    splits its segments there by it (kernels/render.py, substeps)."""
    out = np.zeros(tuple(-(-n // block) for n in density.shape), np.float32)
    densest_near_blocks(np.ascontiguousarray(density, np.float32), block, out)
    return out


def occupied_cells(density: np.ndarray) -> np.ndarray:
    """uint8 (nx, ny, nz): 1 where the cell between the voxel centres (i, j, k) and (i + 1, j +
    1, k + 1) has a voxel of density > 0 among its eight corners (within the grid), else 0. A
    trilinear stencil whose lower corner is (i, j, k) reads only those voxels (its upper index
    is clamped to the grid), so where this is 0 the density there is 0 and the march does not
    interpolate it (kernels/render.py, medium_at)."""
    cell = density > 0
    for axis in range(3):             # each voxel or its upper neighbour along the axis
        upper = np.zeros_like(cell)
        upper[(slice(None),) * axis + (slice(0, -1),)] = cell[(slice(None),) * axis + (slice(1, None),)]
        cell = cell | upper
    return cell.astype(np.uint8)


def skip_blocks(densest: np.ndarray, reach: int = SKIP_REACH) -> np.ndarray:
    """float32 of ``densest``'s shape (:func:`densest_in_blocks`), the coarse grid the march
    reads (kernels/render.py, block_at): ``densest`` where it is > 0; at an empty block, -n with
    n the Chebyshev distance (in blocks) to the nearest non-empty block, at most ``reach`` (and
    ``reach`` where there is none), so every block within n - 1 of it is empty too and a ray
    in it may jump to where it leaves that cube of blocks."""
    occupied = densest > 0
    distance = np.where(occupied, 0, reach).astype(np.float32)
    near = occupied
    for n in range(1, reach):         # near: within n of an occupied block, grown one block a step
        near = voxels_seen(near)
        distance[near & (distance == reach)] = n
        if near.all():
            break
    return np.where(occupied, densest, -distance).astype(np.float32)


def background_map(scene: Scene) -> np.ndarray:
    """float32 (1, 1, 3) constant background, or the environment map (H, 2H, 3)."""
    if scene.environment is not None:
        return scene.environment.radiance
    return np.asarray(scene.background, np.float32).reshape(1, 1, 3)
