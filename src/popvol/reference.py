"""The unbiased reference: any popvol scene as the same scene for Mitsuba 3, rendered in passes.

Conventions matched (each checked by tests/test_reference.py against popvol's own renderer on an
empty, an absorbing-only and an optically thin medium):

- Axis order: popvol's density is indexed [x, y, z]; Mitsuba's ``VolumeGrid`` takes an array
  [z, y, x, channel] (x fastest in memory, as in .vol files), so the array is transposed.
- Voxel centres vs cell corners: both put the grid's voxels as CELLS filling the medium's box
  (``Medium.bounds``), values at cell centres, trilinear in between and clamped to the edge in
  the outer half cell. The ``gridvolume``'s unit cube is mapped onto that box.
- The medium's boundary is a ``cube`` with a ``null`` BSDF over the same box, ``heterogeneous``
  interior with sigma_t = scale * density, a constant albedo and an ``hg`` phase with the same g
  (g > 0 forward in both).
- Lights: a popvol directional light's ``direction`` is the direction the light travels, as
  Mitsuba's ``directional`` emitter; ``irradiance`` is on a plane facing the light in both. A
  point light is Mitsuba's ``point`` emitter, ``intensity`` in W/sr in both.
- Background: a ``constant`` emitter with the background radiance. In Mitsuba it also lights the
  medium, as a sky would; popvol's constant background is only seen, not propagated, so scenes
  meant to measure popvol's accuracy use a black background, or an environment light (``envmap``
  or ``sky``), which is exported as Mitsuba's ``envmap`` and lights the medium in both.
- Camera: ``perspective`` sensor, ``fov_axis = "y"`` (popvol's fov is vertical), ``look_at`` with
  the same origin, target and up; Mitsuba's image x axis runs along -(camera x) of its look-at
  frame, which is popvol's "right" (tests check the orientation with an off-centre blob).
- Film: ``hdrfilm`` with a ``box`` reconstruction filter, the pixel's mean (popvol samples its
  centre at one sample per pixel and jitters uniformly in it at more), linear RGB.
- Integrator: ``volpath`` with ``max_depth`` (default 1024) and Russian roulette from depth 32.

Reference images are accumulated over passes: ``REF.exr`` holds the mean, ``REF.exr.json`` the
sample count and provenance (the scene file relative to the reference's folder, so that the
metadata names no path of the machine that made it), ``REF.exr.npz`` the per-pixel sum and sum
of squares of the pass means (float64), from which the reference's own noise is estimated, and
``sum_b``, the sum over a subset B of the passes (``passes_b`` of them in the metadata): the
passes of odd number, and all the passes added to a reference made before B was kept. The
passes in B and those outside it are two independent images of the same scene
(:attr:`Reference.halves`), so that pixels can be ranked by one and measured against the other
(:func:`popvol.metrics.band_ratios`). The metadata also keeps two digests of the scene:
``scene_digest`` (:func:`scene_digest`) and ``path_traced_digest`` (:func:`path_traced_digest`,
what Mitsuba saw), by which ``popvol compare`` refuses a reference of another scene.
:func:`load_reference` checks the three files, and against each other.
"""
from __future__ import annotations

import glob
import hashlib
import json
import math
import os
import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import check
from .camera import MAX_PIXELS, MAX_SIDE
from .errors import PopvolError
from .io.files import write_atomically, write_text_atomically
from .scene import Scene

VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
MAX_SPP = 2 ** 31 - 1      # Mitsuba takes samples per pixel, and path lengths, as 32-bit integers
#: The longest Mitsuba time a reference's metadata may record (``seconds``): about 32 years
MAX_SECONDS = 1e9
#: The reference's image is the mean of its passes, sum / passes, written as float32 (Mitsuba's
#: rounding residue zeroed, load_reference): it must agree with the sums this closely (relative
#: to the pixel, and to the brightest pixel), loosely enough for a copy saved as half floats
SUMS_RTOL, SUMS_ATOL = 1e-3, 1e-4


def import_mitsuba(variant: str = "scalar_rgb"):
    """``mitsuba`` with ``variant`` set, or a PopvolError saying how to get it."""
    if variant not in VARIANTS:
        raise PopvolError(f"--variant {variant!r}; allowed: {', '.join(VARIANTS)}")
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        # Dr.Jit needs LLVM >= 16 (it emits fminimum); Debian bookworm's default libLLVM-14/15
        # cannot select it. Prefer the newest system libLLVM.
        found = sorted(glob.glob("/usr/lib/*/libLLVM*.so*") + glob.glob("/usr/lib/libLLVM*.so*"),
                       key=_llvm_version)
        if found and _llvm_version(found[-1]) >= 16:
            os.environ["DRJIT_LIBLLVM_PATH"] = found[-1]
    try:
        import mitsuba as mi
    except ImportError:
        raise PopvolError("the reference renderer needs Mitsuba 3: pip install 'popvol[reference]' "
                          "(or pip install mitsuba)") from None
    try:
        mi.set_variant(variant)
    except (ImportError, AttributeError, RuntimeError) as e:
        hint = (" (llvm_ad_rgb needs a system libLLVM >= 16, e.g. apt-get install libllvm19, or "
                "DRJIT_LIBLLVM_PATH pointing at it)" if variant.startswith("llvm") else "")
        raise PopvolError(f"Mitsuba variant {variant!r} is not available: {e}{hint}") from None
    return mi


def _llvm_version(path: str) -> int:
    digits = "".join(c if c.isdigit() else " " for c in Path(path).name).split()
    return int(digits[0]) if digits else 0


def mitsuba_dict(scene: Scene, mi, max_depth: int = 1024, spp: int = 16) -> dict:
    """The Mitsuba 3 scene dict of ``scene`` (``mi`` = the imported module with a variant set)."""
    med, cam = scene.medium, scene.camera
    if med.g_per_voxel:
        raise PopvolError(f"{med.source}: Mitsuba 3 takes one g per medium; a per-voxel g grid has no "
                          "reference export")
    lo, hi = med.bounds
    T = mi.ScalarTransform4f
    to_world = T().translate(lo.tolist()).scale((hi - lo).tolist())

    def volume(arr):          # popvol [x, y, z] or [x, y, z, c] -> Mitsuba [z, y, x, c]
        a = arr[..., None] if arr.ndim == 3 else arr
        return {"type": "gridvolume", "grid": mi.VolumeGrid(np.ascontiguousarray(a.transpose(2, 1, 0, 3), np.float32)),
                "filter_type": "trilinear", "to_world": to_world}

    if np.all(med.scale == med.scale[0]):
        sigma_t, scale = volume(med.density), float(med.scale[0])
    else:                     # RGB extinction: a 3-channel grid
        sigma_t, scale = volume(med.density[..., None] * med.scale.astype(np.float32)), 1.0
    if med.albedo_per_voxel:
        albedo = volume(med.albedo)
    elif np.all(med.albedo == med.albedo[0]):
        albedo = float(med.albedo[0])
    else:
        albedo = {"type": "constvolume", "value": {"type": "rgb", "value": med.albedo.tolist()}}
    medium = {"type": "heterogeneous", "albedo": albedo, "scale": scale, "sigma_t": sigma_t,
              "phase": {"type": "hg", "g": float(med.g)}}
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    extent = float(np.linalg.norm(hi - lo) + np.linalg.norm(cam.origin - centre))
    fwd, right, up = cam.basis()
    d = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": int(max_depth), "rr_depth": 32},
        "sensor": {
            "type": "perspective", "fov": float(cam.fov), "fov_axis": "y",
            "near_clip": 1e-4 * extent, "far_clip": 10.0 * extent,
            "to_world": T().look_at(origin=cam.origin.tolist(), target=(cam.origin + fwd).tolist(),
                                    up=up.tolist()),
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },
        "medium_boundary": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                            "to_world": T().translate(centre.tolist()).scale(half.tolist())},
    }
    bg = np.asarray(scene.background, np.float64)
    if scene.environment is not None:        # the map itself lights the scene and is seen
        d["environment"] = {"type": "envmap", "bitmap": mi.Bitmap(scene.environment.radiance)}
    elif np.any(bg > 0):
        d["background"] = {"type": "constant", "radiance": {"type": "rgb", "value": bg.tolist()}}
    for i, light in enumerate(scene.lights):
        if light.from_environment:
            continue
        d[f"light_{i}"] = light.mitsuba()
    return d


def scene_digest(scene: Scene) -> str:
    """A short hash of the scene that popvol lights: the medium, the camera (the image's size
    included), the background, the environment map and every light, the K directional lights
    popvol decomposes an environment into included (so it changes with popvol's decomposition
    and ``lights = K``, which Mitsuba does not see); not the method. :mod:`popvol.sequence`
    keys its frames on it; a reference's metadata keeps it as ``scene_digest``."""
    h = hashlib.sha256()
    med, cam = scene.medium, scene.camera
    h.update(np.ascontiguousarray(med.density).tobytes())
    for v in (med.voxel_size, med.origin, med.scale, med.albedo, med.g, cam.origin, cam.target, cam.up,
              [cam.fov, cam.width, cam.height], scene.background):
        h.update(np.asarray(v, np.float64).tobytes())
    for l in scene.lights:
        h.update(l.digest())
    if scene.environment is not None:
        h.update(np.ascontiguousarray(scene.environment.radiance).tobytes())
    return h.hexdigest()[:16]


def path_traced_digest(scene: Scene) -> str:
    """A short hash of what the path tracer sees (:func:`mitsuba_dict`): the medium (density,
    box, scale, albedo, g), the camera (origin, target, up, fov, width and height), the
    background, the environment map itself and the lights but those popvol decomposed an
    environment into; not the method. A reference's metadata keeps it as
    ``path_traced_digest``: ``popvol compare`` refuses a reference whose digest differs from
    its scene's, and ``popvol reference`` adds passes only to a reference of the same one."""
    h = hashlib.sha256(b"popvol path-traced scene 1")
    med, cam = scene.medium, scene.camera
    h.update(np.asarray(med.density.shape, np.int64).tobytes())
    h.update(np.ascontiguousarray(med.density).tobytes())
    for v in (med.voxel_size, med.origin, med.scale, med.albedo, med.g, cam.origin, cam.target, cam.up,
              [cam.fov, cam.width, cam.height], scene.background):
        h.update(np.asarray(v, np.float64).tobytes())
    for l in scene.lights:
        if not l.from_environment:
            h.update(l.digest())
    if scene.environment is not None:
        h.update(np.ascontiguousarray(scene.environment.radiance).tobytes())
    return h.hexdigest()[:16]


def check_reference_scene(path, meta: dict, scene: Scene) -> None:
    """A one-line PopvolError unless the reference at ``path`` (its metadata ``meta``) was
    rendered for ``scene``, as far as its metadata tells: by ``path_traced_digest``. A
    reference without that digest is not checked (its ``scene_digest`` also covers popvol's
    decomposition of an environment into lights, which Mitsuba does not see)."""
    recorded = meta.get("path_traced_digest")
    if recorded is None or recorded == path_traced_digest(scene):
        return
    meta_path = _sidecars(Path(path))[0]
    made_for = f" ({meta_path.name} names {check._show(meta['scene'])})" if isinstance(meta.get("scene"), str) else ""
    command = f"popvol reference {scene.source}" if Path(scene.source).is_file() else "popvol reference"
    raise PopvolError(f"{path}: was rendered for another scene{made_for}: its medium, lights, camera or "
                      f"background differ from {scene.source}'s; render a reference of this scene ({command} "
                      "-o NEW.exr) and compare with that")


@dataclass
class Reference:
    """A reference image and what is known about its noise."""

    image: np.ndarray          # float32 (H, W, 3): mean of the passes
    spp: int                   # samples per pixel in all
    passes: int
    variance: np.ndarray | None  # float64 (H, W, 3): variance of the mean (None with < 2 passes)
    meta: dict
    #: float64 (H, W, 3) each: the means of the passes outside subset B and in it, two independent
    #: images of the scene (module docstring); None where a reference has no pass in one of them
    halves: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def half_passes(self) -> tuple[int, int] | None:
        """The passes in each of :attr:`halves` (outside subset B, in it): ``meta["passes_b"]``
        in B. None without halves, or without an integer passes_b in [1, passes) (which
        :func:`load_reference` checks)."""
        nb = self.meta.get("passes_b")
        if self.halves is None or not (isinstance(nb, int) and not isinstance(nb, bool) and 1 <= nb < self.passes):
            return None
        return self.passes - nb, nb

    def noise_relmse(self, mask: np.ndarray | None = None) -> float | None:
        """Expected relMSE of this reference against the truth, from its pass-to-pass variance,
        in the scale-free metric of :func:`popvol.metrics.relmse` (same mask, same eps): None
        with fewer than 2 passes. ``mask`` bool (H, W), the pixels that see the medium
        (:func:`popvol.metrics.medium_mask`); default the reference's luminance mask."""
        from .metrics import noise_relmse
        if self.variance is None:
            return None
        return noise_relmse(self.variance, self.image, mask)


def _sidecars(path: Path) -> tuple[Path, Path]:
    return path.with_name(path.name + ".json"), path.with_name(path.name + ".npz")


def _scene_name(source: str, output: Path) -> str:
    """The scene's file relative to the reference's folder (its name alone where there is no
    relative path, e.g. on another drive); a source that is not a file (``<demo scene>``) as is."""
    p = Path(source)
    if not p.is_file():
        return source
    try:
        return Path(os.path.relpath(p.resolve(), output.resolve().parent)).as_posix()
    except ValueError:
        return p.name


def load_reference(path) -> Reference:
    """The reference at ``path`` (an EXR of radiance: finite and >= 0, not black, at most a
    camera's size) with what its sidecars say (popvol reference's REF.exr.json and REF.exr.npz,
    each checked, and checked against each other and the image: the metadata's width and
    height are the image's, its sums divided by its passes are the image)."""
    return _load_reference(path)[0]


def _load_reference(path) -> tuple[Reference, tuple | None]:
    """:func:`load_reference` and the reference's sums (sum, sumsq, sum_b; None without the
    metadata or the sums file)."""
    from .io.images import exr_size, read_exr
    path = Path(path)
    if not path.is_file():
        from .io.files import why_not_file
        raise PopvolError(f"{path}: reference image {why_not_file(path)}")
    width, height = exr_size(path)
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise PopvolError(f"{path}: the reference is {width}x{height} pixels; popvol renders at the reference's "
                          f"size, at most {MAX_SIDE} pixels on a side and {MAX_PIXELS} in all (a camera's limit)")
    image = read_exr(path)
    bad = int((~np.isfinite(image)).sum()) + int((image < 0).sum())
    if bad:
        raise PopvolError(f"{path}: {bad} pixel values are not finite or are negative; a reference holds "
                          "radiance, finite and >= 0")
    if not image.any():
        raise PopvolError(f"{path}: the reference is black (every pixel 0); there is nothing to compare with")
    meta_path, sums_path = _sidecars(path)
    meta, variance, halves, spp, passes, sums = {}, None, None, 0, 1, None
    if meta_path.is_file():
        meta = _read_meta(meta_path)
        spp, passes = meta["spp"], meta.get("passes", 1)
        size = (meta.get("width", width), meta.get("height", height))
        if size != (width, height):
            raise PopvolError(f"{meta_path}: width x height = {size[0]}x{size[1]}, but the image {path.name} is "
                              f"{width}x{height}; the metadata belongs to another reference")
        if sums_path.is_file():
            sums = _read_sums(sums_path, image.shape, path)
            _check_sums_are_image(sums[0], passes, image, sums_path, meta_path, path)
    if sums is not None and passes >= 2:
        s, s2, sb = sums
        mean = s / passes
        variance = np.maximum(s2 / passes - mean ** 2, 0.0) / (passes - 1)
        nb = meta.get("passes_b", 0)
        if sb is not None and 1 <= nb < passes:
            halves = ((s - sb) / (passes - nb), sb / nb)
    return Reference(image, spp, passes, variance, meta, halves), sums


def _read_meta(meta_path: Path) -> dict:
    """A reference's metadata (REF.exr.json): a JSON object, checked: spp (required) an integer
    in [1, MAX_SPP], passes an integer in [1, spp], passes_b (the passes in subset B) an integer
    in [1, passes - 1] (0 with one pass), seconds a number in [0, MAX_SECONDS], width and height
    integers in [1, MAX_SIDE], the digests strings; each but spp where present. The numbers are returned
    as ``int`` (``float`` for seconds)."""
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError, RecursionError) as e:
        reason = "nested too deeply" if isinstance(e, RecursionError) else e
        raise PopvolError(f"{meta_path}: cannot read reference metadata ({reason})") from None
    if not isinstance(meta, dict):
        raise PopvolError(f"{meta_path}: reference metadata must be a JSON object (popvol reference writes one)")
    if "spp" not in meta:
        raise PopvolError(f"{meta_path}: spp (samples per pixel, an integer in [1, {MAX_SPP}]) is missing; "
                          "popvol reference writes it")
    meta["spp"] = spp = _meta_number(meta, "spp", 0, meta_path, int, 1, MAX_SPP)
    passes = _meta_number(meta, "passes", 1, meta_path, int, 1, spp, f" (at most spp = {spp})")
    if "passes" in meta:
        meta["passes"] = passes
    if "passes_b" in meta:
        meta["passes_b"] = _meta_number(meta, "passes_b", 0, meta_path, int, min(1, passes - 1), passes - 1,
                                        f" (passes in subset B, fewer than passes = {passes})")
    if "seconds" in meta:
        meta["seconds"] = _meta_number(meta, "seconds", 0.0, meta_path, float, 0.0, MAX_SECONDS)
    for key in ("width", "height"):
        if key in meta:
            meta[key] = _meta_number(meta, key, 1, meta_path, int, 1, MAX_SIDE)
    for key in ("scene_digest", "path_traced_digest"):
        if key in meta and not isinstance(meta[key], str):
            raise PopvolError(f"{meta_path}: {key} = {check._show(meta[key])} must be a string (popvol reference "
                              "writes a hash of the scene)")
    return meta


#: The arrays of a reference's REF.exr.npz
_SUMS_TEXT = "numpy.savez of sum, sumsq and sum_b, as popvol reference writes them"


def _read_sums(sums_path: Path, shape, image_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A reference's per-pixel sum and sum of squares over its passes and sum over subset B
    (REF.exr.npz; None where the file has no ``sum_b``), float64 of ``shape`` (H, W, 3), the
    image's (``image_path``). Each must be real numbers, finite and >= 0 (the sums but the sum of
    squares down to Mitsuba's float32 rounding residue, -1e-6 of their largest), and ``sum_b``
    at most ``sum``; anything else is a one-line PopvolError naming the file and the array."""
    from .io.volumes import _check_npz_member
    arrays = {}
    try:
        # open the file ourselves: np.load leaks its handle when it rejects a file
        with open(sums_path, "rb") as f, np.load(f, allow_pickle=False) as z:
            for key in ("sum", "sumsq"):
                if key not in z.files:
                    raise PopvolError(f"{sums_path}: has no array {key!r} (arrays in it: {', '.join(z.files) or 'none'}); "
                                      f"the reference's per-pixel sums are a {_SUMS_TEXT}")
            for key in ("sum", "sumsq", "sum_b"):
                if key in z.files:
                    _check_npz_member(z, key, sums_path)
                    arrays[key] = z[key]
    except PopvolError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, NotImplementedError) as e:
        if "pickled" in str(e):             # NumPy's word for anything that is neither zip nor .npy
            raise PopvolError(f"{sums_path}: is not an .npz archive; the reference's per-pixel sums are a "
                              f"{_SUMS_TEXT}") from None
        raise PopvolError(f"{sums_path}: cannot read the reference's per-pixel sums ({_SUMS_TEXT}): {e}") from None
    except (TypeError, AttributeError):     # np.load gave a plain array: .npy content
        raise PopvolError(f"{sums_path}: holds a single .npy array, not an .npz archive; the reference's per-pixel "
                          f"sums are a {_SUMS_TEXT}") from None
    shape = tuple(shape)
    for key, a in arrays.items():
        if a.shape != shape:
            raise PopvolError(f"{sums_path}: {key} has shape {a.shape}, but the image {image_path.name} is "
                              f"{shape[1]}x{shape[0]}: it must have shape {shape} (the file belongs to another "
                              "reference)")
        if a.dtype.kind not in "fiu":
            raise PopvolError(f"{sums_path}: {key} has dtype {a.dtype}; the sums are real numbers (float64)")
    out = {key: np.asarray(a, np.float64) for key, a in arrays.items()}
    with np.errstate(invalid="ignore"):
        top = float(np.max(np.where(np.isfinite(out["sum"]), out["sum"], 0.0)))
        floor = -1e-6 * max(top, 0.0)       # Mitsuba's film leaves float32 rounding residue below 0
        for key, a in out.items():
            bad = ~np.isfinite(a) | (a < (0.0 if key == "sumsq" else floor))
            if bad.any():
                y, x, _ = (int(v) for v in np.argwhere(bad)[0])
                raise PopvolError(f"{sums_path}: {key} has {int(bad.sum())} values that are NaN, infinite or "
                                  f"negative (the first at pixel x = {x}, y = {y}); sums of radiance over the "
                                  "passes are finite and >= 0")
    if "sum_b" in out:
        over = out["sum_b"] > out["sum"] + 1e-6 * top + 1e-9 * np.abs(out["sum"])
        if over.any():
            y, x, _ = (int(v) for v in np.argwhere(over)[0])
            raise PopvolError(f"{sums_path}: sum_b exceeds sum at {int(over.sum())} values (the first at pixel "
                              f"x = {x}, y = {y}); sum_b sums a subset of the passes that sum sums")
    return out["sum"], out["sumsq"], out.get("sum_b")


def _check_sums_are_image(s: np.ndarray, passes: int, image: np.ndarray, sums_path: Path, meta_path: Path,
                          path: Path) -> None:
    """A one-line PopvolError unless sum / passes is the reference's image (within SUMS_RTOL of
    each pixel and SUMS_ATOL of the brightest): otherwise the metadata's passes or the sums
    belong to another reference."""
    mean, img = s / passes, image.astype(np.float64)
    off = np.abs(mean - img) - (SUMS_RTOL * np.abs(img) + SUMS_ATOL * float(img.max()))
    if np.any(off > 0):
        y, x, c = (int(v) for v in np.unravel_index(int(np.argmax(off)), off.shape))
        raise PopvolError(f"{sums_path}: sum / passes (passes = {passes} in {meta_path.name}) is "
                          f"{mean[y, x, c]:.6g} at pixel x = {x}, y = {y} where the image {path.name} holds "
                          f"{img[y, x, c]:.6g}; the sums or the passes belong to another reference (render it again "
                          "with popvol reference --new)")


def _meta_number(meta: dict, key: str, default, meta_path: Path, kind, minimum, maximum=math.inf, why: str = ""):
    """meta[key] (``default`` where absent) as ``kind``, finite and in [``minimum``, ``maximum``]
    (``why``: what the range is, said after it)."""
    value = meta.get(key, default)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    ok = number and (isinstance(value, int) or (math.isfinite(value) and (kind is float or value.is_integer())))
    if not ok or (key in meta and not minimum <= value <= maximum):
        what = "an integer" if kind is int else "a number"
        lo, hi = (f"{v:g}" if isinstance(v, float) else v for v in (minimum, maximum))
        allowed = f">= {lo}" if maximum == math.inf else f"in [{lo}, {hi}]"
        raise PopvolError(f"{meta_path}: {key} = {check._show(value)} must be {what} {allowed}{why}")
    return kind(value)


def render_reference(scene: Scene, output, spp: int, variant: str = "scalar_rgb", passes: int = 4,
                     max_depth: int = 1024, resume: bool = True, progress=None) -> Reference:
    """Render ``spp`` more samples per pixel in ``passes`` passes and add them to ``output``.
    ``spp`` must be a multiple of ``passes`` (each pass renders the same samples per pixel);
    more passes than samples are cut to one sample each.

    With ``resume`` and an existing reference of the same scene (the same
    :func:`path_traced_digest`, or for a reference made before popvol kept it the same
    :func:`scene_digest`), its passes are kept and the new ones added; a reference of another
    scene is an error, and so is one that :func:`load_reference` refuses (checked before
    Mitsuba runs) or one that would pass MAX_SPP samples per pixel.
    """
    from .io.images import write_exr
    output = Path(output)
    for flag, value in (("--spp", spp), ("--passes", passes)):
        if not 1 <= value <= MAX_SPP:
            raise PopvolError(f"{flag} = {value} must be in [1, {MAX_SPP}]")
    passes = min(passes, spp)
    if spp % passes:
        lower, higher = spp // passes * passes, -(-spp // passes) * passes
        divisors = [d for d in range(2, min(spp, 64) + 1) if spp % d == 0]
        instead = f", or --passes {', '.join(map(str, divisors))}" if divisors else ""
        raise PopvolError(f"--spp = {spp} is not a multiple of --passes = {passes} (every pass takes the same "
                          f"samples per pixel): use --spp {lower} or {higher}{instead}")
    if max_depth != -1 and not 2 <= max_depth <= MAX_SPP:
        raise PopvolError(f"--max-depth = {max_depth} must be -1 (no limit) or in [2, {MAX_SPP}] "
                          "(a path of length 1 sees no scattering)")
    per_pass = spp // passes
    meta_path, sums_path = _sidecars(output)
    digest, traced = scene_digest(scene), path_traced_digest(scene)
    s = s2 = sb = None
    done_passes = done_spp = nb = 0
    old = False                 # a reference made before subset B was kept: new passes form B
    seconds = 0.0
    if resume and output.exists():
        if not (meta_path.is_file() and sums_path.is_file()):
            raise PopvolError(f"{output}: exists without its {meta_path.name} / {sums_path.name}; "
                              "remove it or choose another output to start a new reference")
        meta = _read_meta(meta_path)
        ref, (s, s2, sb) = _load_reference(output)
        # the size first: both digests cover it, and a size is what --width / --height change
        if ref.image.shape[:2] != (scene.camera.height, scene.camera.width):
            raise PopvolError(f"{output}: is {ref.image.shape[1]}x{ref.image.shape[0]} pixels; resume at that size "
                              f"(now {scene.camera.width}x{scene.camera.height}) or choose another output")
        same = (meta["path_traced_digest"] == traced if "path_traced_digest" in meta
                else meta.get("scene_digest") == digest)
        if not same:
            raise PopvolError(f"{output}: was rendered for another scene ({check._show(meta.get('scene'))}); "
                              "choose another output")
        done_passes, done_spp = ref.passes, ref.spp
        old = sb is None or "passes_b" not in meta      # sum_b without its count: start B afresh
        nb = 0 if old else meta["passes_b"]
        if old:
            sb = np.zeros_like(s)
        seconds = float(meta.get("seconds", 0.0))
        if _meta_number(meta, "max_depth", 1024, meta_path, int, -1) != max_depth:
            raise PopvolError(f"{output}: was rendered with --max-depth {meta.get('max_depth', 1024)}; resume "
                              f"with the same (now {max_depth}) or choose another output")
        if _meta_number(meta, "spp_per_pass", 0, meta_path, int, 1) != per_pass:
            raise PopvolError(f"{output}: has {meta.get('spp_per_pass')} samples per pass; resume "
                              f"with --spp / --passes giving the same (now {per_pass})")
        if done_spp + per_pass * passes > MAX_SPP:
            raise PopvolError(f"{output}: has {done_spp} spp; {per_pass * passes} more would pass {MAX_SPP} "
                              "(the most a reference records); choose another output")
    mi = import_mitsuba(variant)
    mscene = mi.load_dict(mitsuba_dict(scene, mi, max_depth, per_pass))
    for p in range(passes):
        t0 = time.perf_counter()
        img = np.asarray(mi.render(mscene, spp=per_pass, seed=done_passes + p), np.float64)[..., :3]
        seconds += time.perf_counter() - t0
        s = img if s is None else s + img
        s2 = img ** 2 if s2 is None else s2 + img ** 2
        if sb is None:
            sb = np.zeros_like(img)
        if old or (done_passes + p) % 2 == 1:
            sb += img
            nb += 1
        if progress is not None:
            progress(p + 1, passes)
    n = done_passes + passes
    mean = s / n
    # Mitsuba's films leave float32 rounding residue (-1e-17 in empty pixels, -5e-9 beside 0.4)
    # in the sums: zero it, but let anything larger than float32 rounding of the brightest
    # pixel (a real negative radiance) reach write_exr's check
    mean = np.where((mean < 0) & (mean > -1e-6 * max(float(mean.max()), 1e-30)), 0.0, mean)
    mean = mean.astype(np.float32)
    write_exr(output, mean)
    write_atomically(sums_path, lambda tmp: np.savez(tmp, sum=s, sumsq=s2, sum_b=sb))
    meta = {"scene": _scene_name(scene.source, output), "scene_digest": digest, "path_traced_digest": traced,
            "spp": done_spp + per_pass * passes, "passes": n, "passes_b": nb, "spp_per_pass": per_pass,
            "variant": variant, "max_depth": max_depth, "integrator": "volpath",
            "mitsuba": mi.__version__, "seconds": seconds,
            "width": scene.camera.width, "height": scene.camera.height}
    write_text_atomically(meta_path, json.dumps(meta, indent=2))
    return load_reference(output)
