"""A scene is plain data: a dict (or a TOML file) of medium, lights, background, camera, method.

Objects are chosen by ``type`` (as in Mitsuba 3). The schema, with every default, is in
``docs/SCENE.md`` and ``examples/demo.toml``. Validation happens here, once: every error is a
one-line :class:`PopvolError` naming the file, the field and the allowed range.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import PopvolError
from .lights import DirectionalLight, PointLight
from .medium import Medium

SOLVERS = ("sweep", "jacobi")
ISOTROPIC = ("walk", "diffusion")
RULES = ("moment", "paper")
DECAYS = ("poisson", "paper")


@dataclass
class Method:
    """How the light is propagated and the image rendered (see docs/SCENE.md).

    resolution: cells along the longest side of each light's propagation domain.
    solver: "sweep" (Gauss-Seidel sweeps along the light, fast) or "jacobi" (wavefront iteration,
        the reference semantics: every iteration moves each packet by one cell).
    rule: anisotropy carried by each outgoing part: "moment" (conditional mean cosine of its slice
        of the lobe, conserves the first angular moment) or "paper" (every part keeps +a).
    decay: anisotropy decay per step: "poisson" exp(-sigma_s s (1 - g)) or "paper" g^(sigma_s s).
    isotropic: what happens to light whose lobe has spread: "walk" (it keeps walking cell by
        cell, the papers' POP) or "diffusion" (it leaves the walk for a diffusion solve with the
        physical coefficient 1 / (3 sigma_tr); see popvol/diffusion.py).
    handover_scale: with "diffusion", a packet leaves the walk when its |a| <
        handover_scale * (1 - exp(-sigma_tr s)), s the cell size (propagate.handover_factor).
    diffusion_resolution: cells along the longest side of the diffusion grid (blocks of the
        light's domain; 0 = the domain's own cells).
    environment_resolution: ``resolution`` of the domains of an environment's K lights (they
        cast soft light; 0 = ``resolution``).
    tolerance: stop when the energy still in flight is below tolerance * injected energy.
    max_iterations: cap on iterations (jacobi) or sweeps (sweep); 0 = automatic.
    step: ray-marching step in medium voxels.
    spp: jittered samples per pixel.
    exposure: PNG exposure in stops (EXR stays linear).
    seed: seed of the pixel jitter.
    """

    resolution: int = 128
    solver: str = "sweep"
    rule: str = "moment"
    decay: str = "poisson"
    isotropic: str = "diffusion"
    handover_scale: float = 2.0
    diffusion_resolution: int = 64
    environment_resolution: int = 64
    tolerance: float = 1e-3
    max_iterations: int = 0
    step: float = 0.5
    spp: int = 1
    exposure: float = 0.0
    seed: int = 0

    def validate(self, src: str) -> "Method":
        _int_in(self.resolution, "method.resolution", src, 2, 4096)
        _choice(self.solver, "method.solver", src, SOLVERS)
        _choice(self.rule, "method.rule", src, RULES)
        _choice(self.decay, "method.decay", src, DECAYS)
        _choice(self.isotropic, "method.isotropic", src, ISOTROPIC)
        _float_in(self.handover_scale, "method.handover_scale", src, 0.0, 100.0)
        _int_in(self.diffusion_resolution, "method.diffusion_resolution", src, 0, 4096)
        if self.environment_resolution != 0:
            _int_in(self.environment_resolution, "method.environment_resolution", src, 2, 4096)
        _float_in(self.tolerance, "method.tolerance", src, 1e-12, 1.0)
        _int_in(self.max_iterations, "method.max_iterations", src, 0, 10_000_000)
        _float_in(self.step, "method.step", src, 1e-3, 16.0)
        _int_in(self.spp, "method.spp", src, 1, 4096)
        _float_in(self.exposure, "method.exposure", src, -64.0, 64.0)
        _int_in(self.seed, "method.seed", src, 0, 2**63 - 1)
        return self


@dataclass
class Scene:
    medium: Medium
    lights: list[DirectionalLight | PointLight]
    camera: Camera
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    method: Method = field(default_factory=Method)
    source: str = "<scene>"
    environment: object = None     # envmap.EnvMap: the background, and the source of some lights


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------

_TOP_KEYS = {"medium", "lights", "light", "background", "camera", "method"}
_MEDIUM_KEYS = {"type", "file", "grid", "resolution", "seed", "extent", "scale", "albedo", "g",
                "voxel_size", "origin"}
_LIGHT_KEYS = {"directional": {"type", "direction", "irradiance", "a0"},
               "point": {"type", "position", "intensity"},
               "envmap": {"type", "file", "scale", "lights"},
               "sky": {"type", "zenith", "horizon", "ground", "lights"}}
_CAMERA_KEYS = {"origin", "target", "up", "fov", "width", "height"}
_BACKGROUND_KEYS = {"type", "radiance"}


def load_scene(path: str | Path | None = None, **overrides) -> Scene:
    """Load a scene from a TOML file; ``None`` gives the built-in demo scene.

    ``overrides`` replace method/camera fields after loading, e.g. ``width=320, resolution=64``.
    """
    if path is None:
        scene = scene_from_dict(DEMO_SCENE, source="<demo scene>")
    else:
        p = Path(path)
        if not p.is_file():
            raise PopvolError(f"{p}: scene file not found" if not p.exists() else f"{p}: not a file")
        try:
            data = tomllib.loads(p.read_text())
        except (OSError, UnicodeDecodeError) as e:
            raise PopvolError(f"{p}: cannot read scene file ({e})") from None
        except tomllib.TOMLDecodeError as e:
            raise PopvolError(f"{p}: invalid TOML ({e})") from None
        scene = scene_from_dict(data, source=str(p), base_dir=p.parent)
    return apply_overrides(scene, **overrides) if overrides else scene


def apply_overrides(scene: Scene, **overrides) -> Scene:
    """Replace camera fields (width, height, fov) and method fields; validated again."""
    cam_fields = {k: v for k, v in overrides.items() if k in ("width", "height", "fov") and v is not None}
    meth_fields = {k: v for k, v in overrides.items() if k not in cam_fields and v is not None}
    for k in meth_fields:
        if not hasattr(scene.method, k):
            raise PopvolError(f"unknown override {k!r}")
    if cam_fields:
        c = scene.camera
        scene.camera = Camera(c.origin, c.target, c.up, cam_fields.get("fov", c.fov),
                              cam_fields.get("width", c.width), cam_fields.get("height", c.height),
                              source=c.source)
    for k, v in meth_fields.items():
        setattr(scene.method, k, v)
    scene.method.validate(scene.source + " (override)")
    return scene


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path = ".") -> Scene:
    """Build and validate a :class:`Scene` from plain data (the TOML structure as a dict)."""
    if not isinstance(data, dict):
        raise PopvolError(f"{source}: a scene must be a table/dict, got {type(data).__name__}")
    _known(data, _TOP_KEYS, "", source)
    if "medium" not in data:
        raise PopvolError(f"{source}: missing [medium] table")
    medium = _medium(_table(data, "medium", source), source, Path(base_dir))

    raw_lights = data.get("lights", data.get("light", []))
    if isinstance(raw_lights, dict):
        raw_lights = [raw_lights]
    if not isinstance(raw_lights, list) or not raw_lights:
        raise PopvolError(f"{source}: lights must be a non-empty list of [[lights]] tables")
    lights, environment = [], None
    for i, l in enumerate(raw_lights):
        got = _light(l, f"lights[{i}]", source, Path(base_dir))
        if isinstance(got, list):                  # an environment, decomposed
            if environment is not None:
                raise PopvolError(f"{source}: lights[{i}]: only one environment light (envmap or sky) per scene")
            environment, got = got
        lights += got if isinstance(got, list) else [got]
        if isinstance(got, PointLight):
            from .domains import check_point_distance
            check_point_distance(medium, got.position, f"{source}: lights[{i}].position")

    bg = data.get("background", {})
    if not isinstance(bg, dict):
        raise PopvolError(f"{source}: background must be a table")
    _known(bg, _BACKGROUND_KEYS, "background.", source)
    if bg.get("type", "constant") != "constant":
        raise PopvolError(f"{source}: background.type = {bg['type']!r}; allowed: 'constant'")
    if environment is not None and "radiance" in bg:
        raise PopvolError(f"{source}: background.radiance is given, but the background of a scene with "
                          "an environment light is the environment map itself; remove it")
    background = _rgb(bg.get("radiance", 0.0), "background.radiance", source)

    method = Method(**_method_fields(data.get("method", {}), source)).validate(source)
    camera = _camera(data.get("camera"), medium, source)
    return Scene(medium, lights, camera, background, method, source, environment)


def _medium(m: dict, src: str, base: Path) -> Medium:
    _known(m, _MEDIUM_KEYS, "medium.", src)
    kind = m.get("type", "file" if "file" in m else "procedural")
    optics = {k: m[k] for k in ("scale", "albedo", "g") if k in m}
    for key in ("albedo", "g"):              # per-voxel grids: {file = "...", grid = "..."}
        if isinstance(optics.get(key), dict):
            optics[key] = _optics_grid(optics[key], key, m, src, base)
    if kind == "procedural":
        from .procedural import demo_medium
        res = _int_in(m.get("resolution", 96), "medium.resolution", src, 8, 1024)
        seed = _int_in(m.get("seed", 7), "medium.seed", src, 0, 2**32 - 1)
        extent = _float_in(m.get("extent", 2.0), "medium.extent", src, 1e-9, 1e12)
        med = demo_medium(res, seed, extent)
        return Medium(med.density, med.voxel_size, med.origin, source=src, **_optics(med, optics))
    if kind == "file":
        from .io.volumes import read_volume
        if "file" not in m:
            raise PopvolError(f"{src}: medium.type = 'file' needs medium.file")
        path = Path(m["file"])
        if not path.is_absolute():
            path = base / path
        vol = read_volume(path, m.get("grid"))
        voxel = m.get("voxel_size", vol.voxel_size)
        origin = m.get("origin", vol.origin)
        return Medium(vol.density, voxel, origin, source=src, **_optics(None, optics))
    raise PopvolError(f"{src}: medium.type = {kind!r}; allowed: 'procedural', 'file'")


def _optics_grid(spec: dict, key: str, m: dict, src: str, base: Path) -> np.ndarray:
    """A per-voxel albedo or g grid: ``{file = ..., grid = ...}`` (file defaults to the medium's,
    grid to the key's name). The grid must match the density's shape (checked by Medium)."""
    from .io.volumes import read_volume
    _known(spec, {"file", "grid"}, f"medium.{key}.", src)
    if "file" not in spec and "file" not in m:
        raise PopvolError(f"{src}: medium.{key} is a grid table but names no file (and the medium has none)")
    path = Path(spec.get("file", m.get("file")))
    if not path.is_absolute():
        path = base / path
    return read_volume(path, spec.get("grid", key), signed=(key == "g")).density


def _optics(med, given: dict) -> dict:
    out = {"scale": 1.0, "albedo": 1.0, "g": 0.0}
    if med is not None:
        out.update(scale=med.scale, albedo=med.albedo, g=med.g)
    out.update(given)
    return out


def _light(l, name: str, src: str, base: Path = Path(".")):
    """A DirectionalLight or PointLight, or for an environment [EnvMap, its K directional lights]."""
    if not isinstance(l, dict):
        raise PopvolError(f"{src}: {name} must be a table")
    kind = l.get("type", "directional")
    if kind not in _LIGHT_KEYS:
        raise PopvolError(f"{src}: {name}.type = {kind!r}; allowed: {', '.join(repr(k) for k in _LIGHT_KEYS)}")
    _known(l, _LIGHT_KEYS[kind], f"{name}.", src)
    if kind in ("envmap", "sky"):
        from . import envmap
        k = _int_in(l.get("lights", 12), f"{name}.lights", src, 1, 256)
        if kind == "envmap":
            if "file" not in l:
                raise PopvolError(f"{src}: {name}.file is required (an OpenEXR lat-long map)")
            path = Path(l["file"])
            env = envmap.load(path if path.is_absolute() else base / path,
                              _rgb(l.get("scale", 1.0), f"{name}.scale", src))
        else:
            env = envmap.sky(_rgb(l.get("zenith", [0.2, 0.35, 0.8]), f"{name}.zenith", src),
                             _rgb(l.get("horizon", [0.6, 0.7, 0.9]), f"{name}.horizon", src),
                             _rgb(l.get("ground", 0.0), f"{name}.ground", src), source=f"{src}: {name}")
        return [env, envmap.decompose(env, k)]
    if kind == "point":
        if "position" not in l:
            raise PopvolError(f"{src}: {name}.position is required (the light's world position)")
        return PointLight(l["position"], _rgb(l.get("intensity", 1.0), f"{name}.intensity", src),
                          source=f"{src}: {name}")
    if "direction" not in l:
        raise PopvolError(f"{src}: {name}.direction is required (the direction the light travels)")
    return DirectionalLight(l["direction"], _rgb(l.get("irradiance", 1.0), f"{name}.irradiance", src),
                            a0=_float_in(l.get("a0", 1.0), f"{name}.a0", src, 0.0, 1.0), source=f"{src}: {name}")


def _camera(c, medium: Medium, src: str) -> Camera:
    if c is None:
        return auto_camera(medium, source=src)
    if not isinstance(c, dict):
        raise PopvolError(f"{src}: camera must be a table")
    _known(c, _CAMERA_KEYS, "camera.", src)
    auto = auto_camera(medium, source=src)
    return Camera(c.get("origin", auto.origin), c.get("target", auto.target), c.get("up", (0, 1, 0)),
                  c.get("fov", 40.0), c.get("width", 640), c.get("height", 360), source=src)


def auto_camera(medium: Medium, width: int = 640, height: int = 360, fov: float = 40.0,
                source: str = "<camera>") -> Camera:
    """A camera in front of the medium (+z side, slightly above) that frames its bounding sphere."""
    lo, hi = medium.bounds
    centre = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo)
    view = np.array([0.0, 0.15, 1.0])
    view /= np.linalg.norm(view)
    dist = radius / np.sin(np.radians(fov) / 2) * 0.95
    return Camera(centre + dist * view, centre, (0, 1, 0), fov, width, height, source=source)


def _method_fields(m, src: str) -> dict:
    if not isinstance(m, dict):
        raise PopvolError(f"{src}: method must be a table")
    known = set(Method.__dataclass_fields__)
    if "handover" in m:
        raise PopvolError(f"{src}: method.handover (a fixed |a| threshold) was replaced by "
                          "method.handover_scale (the threshold per cell is handover_scale * "
                          "(1 - exp(-sigma_tr s)), default 2; see docs/SCENE.md): remove the key or rename it")
    _known(m, known, "method.", src)
    return dict(m)


# -- small validators --------------------------------------------------------------------------

def _table(data: dict, key: str, src: str) -> dict:
    t = data[key]
    if not isinstance(t, dict):
        raise PopvolError(f"{src}: {key} must be a table")
    return t


def _known(d: dict, known: set, prefix: str, src: str):
    for k in d:
        if k not in known:
            raise PopvolError(f"{src}: unknown key {prefix}{k} (known: {', '.join(sorted(known))})")


def _rgb(v, name: str, src: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise PopvolError(f"{src}: {name} must be a number or 3 numbers, got {v!r}") from None
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise PopvolError(f"{src}: {name} = {v!r} must be one or three finite numbers >= 0")
    return a


def _int_in(v, name: str, src: str, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
        raise PopvolError(f"{src}: {name} = {v!r} must be an integer in [{lo}, {hi}]")
    return int(v)


def _float_in(v, name: str, src: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (lo <= v <= hi):
        raise PopvolError(f"{src}: {name} = {v!r} must be a number in [{lo:g}, {hi:g}]")
    return float(v)


def _choice(v, name: str, src: str, allowed) -> str:
    if v not in allowed:
        raise PopvolError(f"{src}: {name} = {v!r}; allowed: {', '.join(repr(a) for a in allowed)}")
    return v


#: The built-in demo: the procedural cumulus lit by a sun behind it to the right, seen against a
#: blue sky.
DEMO_SCENE = {
    "medium": {"type": "procedural", "resolution": 96, "seed": 7, "extent": 2.0,
               "scale": 12.0, "albedo": 0.99, "g": 0.85},
    "lights": [{"type": "directional", "direction": [-0.8, -0.45, 0.2],
                "irradiance": [3.0, 2.9, 2.7]}],
    "background": {"type": "constant", "radiance": [0.30, 0.45, 0.75]},
    "camera": {"origin": [0.0, 0.7, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0,
               "width": 640, "height": 360},
    "method": {"exposure": 0.5},
}
