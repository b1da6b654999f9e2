"""A scene is plain data: a dict (or a TOML file) of medium, lights, background, camera, method
and, for the variants of the accuracy study, experimental.

Objects are chosen by ``type`` (as in Mitsuba 3). The schema, with every default, is in
``docs/SCENE.md`` and ``examples/demo.toml``; the method's knobs are declared in
:mod:`popvol.method`. Values are checked with :mod:`popvol.check`: every error is a one-line
:class:`PopvolError` naming the file, the field and the allowed range.
"""
from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import check
from .camera import Camera
from .errors import PopvolError
from .io.files import file_name, why_missing
from .lights import LIGHTS, Light
from .medium import Medium, check_box
from .method import KNOB, Method, mark_overridden, method_from_tables

__all__ = ["Scene", "Method", "load_scene", "apply_overrides", "scene_from_dict", "auto_camera",
           "DEMO_SCENE"]


@dataclass
class Scene:
    medium: Medium
    lights: list[Light]
    camera: Camera
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    method: Method = field(default_factory=Method)
    source: str = "<scene>"
    environment: object = None     # envmap.EnvMap: the background, and the source of some lights
    files: tuple[Path, ...] = ()   # the files it reads (medium, grids, maps), resolved
    frame: int | None = None       # its frame of a sequence (popvol.sequence), None for a still scene
    hidden: bool = False           # the frame is outside medium.frames and medium.mode = "clip" hides the medium


def checked_scene(scene, what: str) -> "Scene":
    """``scene`` as :func:`popvol.solve` and :func:`popvol.render` take it: a Scene whose parts
    are checked again, as the loader checks them (a method, camera, light or medium changed
    after loading, or a Scene built by hand, gets the loader's one-line PopvolError naming the
    field, not a crash or a wrong image). The camera and lights are built again through their
    own checks, the medium only where it is no longer :meth:`Medium.intact`, the method's
    knobs validated in place. ``what``: the call, for a wrong type ("solve")."""
    if not isinstance(scene, Scene):
        raise PopvolError(f"{what}: scene must be a popvol Scene (popvol.load_scene, popvol.scene_from_dict), "
                          f"not {type(scene).__name__}")
    src = scene.source
    for name, value, kind in (("medium", scene.medium, Medium), ("camera", scene.camera, Camera),
                              ("method", scene.method, Method)):
        if not isinstance(value, kind):
            raise PopvolError(f"{src}: scene.{name} must be a popvol {kind.__name__}, not {type(value).__name__}")
    lights = scene.lights
    if not isinstance(lights, (list, tuple)) or not all(isinstance(l, Light) for l in lights) or (
            not lights and scene.environment is None):     # an environment map of zeros gives no light
        raise PopvolError(f"{src}: scene.lights must be a non-empty list of popvol lights (popvol.LIGHTS), "
                          f"not {check._show(lights)}")
    scene.method.validate(src)
    medium = scene.medium if scene.medium.intact() else dataclasses.replace(scene.medium)
    lights = [dataclasses.replace(light) for light in lights]
    for light in lights:
        light.check(medium)
    return dataclasses.replace(scene, medium=medium, lights=lights, camera=dataclasses.replace(scene.camera),
                               background=check.power(scene.background, "background.radiance", src))


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------

_TOP_KEYS = {"medium", "lights", "light", "background", "camera", "method", "experimental", "sequence",
             "keyframes"}
#: frames, mode, offset: a file sequence's keys, read (and removed) by popvol.sequence.frame_data
_MEDIUM_KEYS = {"type", "file", "grid", "resolution", "seed", "extent", "style", "time", "scale", "albedo",
                "g", "voxel_size", "origin", "frames", "mode", "offset"}
#: Environment lights (popvol.envmap): split into directional lights when loaded.
_ENVIRONMENT_KEYS = {"envmap": {"type", "file", "scale", "lights"},
                     "sky": {"type", "zenith", "horizon", "ground", "lights"}}
_CAMERA_KEYS = {"origin", "target", "up", "fov", "width", "height"}
_BACKGROUND_KEYS = {"type", "radiance"}


#: A scene file is a few kB of TOML (volumes live in their own files); Python's TOML parser
#: takes about 2 s per MiB, so a larger file is refused before it is read.
MAX_SCENE_FILE_BYTES = 4 * 2**20


def read_scene_file(path) -> dict:
    """The TOML of scene file ``path`` as a dict; a missing, unreadable, oversized (above
    MAX_SCENE_FILE_BYTES), invalid or too deeply nested (beyond what Python's TOML parser
    recurses into, some 500 levels of arrays or inline tables) file is a one-line PopvolError
    naming it."""
    p = Path(path)
    if not p.is_file():
        raise PopvolError(f"{p}: scene file {why_missing(p)}" if not p.exists() else f"{p}: not a file")
    try:
        size = p.stat().st_size
        if size > MAX_SCENE_FILE_BYTES:
            raise PopvolError(f"{p}: scene file is {size / 2**20:.1f} MiB; at most "
                              f"{MAX_SCENE_FILE_BYTES // 2**20} MiB of TOML is read (a volume goes in its own "
                              "file, named by [medium] file)")
        return tomllib.loads(p.read_text(encoding="utf-8-sig"))    # a byte-order mark (Windows editors) is not TOML
    except (OSError, UnicodeDecodeError) as e:
        raise PopvolError(f"{p}: cannot read scene file ({e})") from None
    except tomllib.TOMLDecodeError as e:
        raise PopvolError(f"{p}: invalid TOML ({e})") from None
    except RecursionError:               # tomllib recurses once per level of [ or {
        raise PopvolError(f"{p}: arrays or inline tables nested too deeply to read (a scene's values nest "
                          "a few levels at most)") from None


def load_scene(path: str | Path | None = None, frame: int | None = None, **overrides) -> Scene:
    """Load a scene from a TOML file; ``None`` gives the built-in demo scene.

    ``frame``: the frame of a sequence (docs/SCENE.md, "Sequences"; None: a sequence's first
    frame, a still scene as written). ``overrides`` replace camera fields (width, height, fov)
    and method fields, experimental ones included, after loading, e.g. ``width=320,
    resolution=64, isotropic="walk"``; ``None`` values are ignored.
    """
    if path is None:
        scene = scene_from_dict(DEMO_SCENE, source="<demo scene>", frame=frame)
    else:
        p = Path(file_name(path, "load_scene: path"))
        scene = scene_from_dict(read_scene_file(p), source=str(p), base_dir=p.parent, frame=frame)
    return apply_overrides(scene, **overrides) if overrides else scene


def apply_overrides(scene: Scene, **overrides) -> Scene:
    """Replace camera fields (width, height, fov) and method fields (any knob of
    :data:`popvol.method.KNOBS`); ``None`` values are ignored. Validated again."""
    cam_fields = {k: v for k, v in overrides.items() if k in ("width", "height", "fov") and v is not None}
    meth_fields = {k: v for k, v in overrides.items() if k not in cam_fields and v is not None}
    for k in meth_fields:
        if k not in KNOB:
            raise PopvolError(f"unknown override {k!r} (known: width, height, fov, {', '.join(KNOB)})")
    if cam_fields:
        c = scene.camera
        scene.camera = Camera(c.origin, c.target, c.up, cam_fields.get("fov", c.fov),
                              cam_fields.get("width", c.width), cam_fields.get("height", c.height),
                              source=c.source + " (override)")     # --width 0 is not the scene's
    for k, v in meth_fields.items():
        setattr(scene.method, k, v)
    mark_overridden(scene.method, meth_fields)     # for messages that name a knob (method.knob_field)
    scene.method.validate(scene.source + " (override)")
    return scene


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path = ".",
                    frame: int | None = None) -> Scene:
    """Build and validate a :class:`Scene` from plain data (the TOML structure as a dict).

    A sequence (``[sequence]``, ``[[keyframes]]``, a medium file with a ``#`` run) or a given
    ``frame`` builds that frame (None: the first), by :func:`popvol.sequence.frame_data`."""
    if not isinstance(data, dict):
        raise PopvolError(f"{source}: a scene must be a table/dict, got {type(data).__name__}")
    file_name(base_dir, "scene_from_dict: base_dir")
    check.known_keys(data, _TOP_KEYS, "", source)
    hidden = False
    if frame is not None or "sequence" in data or "keyframes" in data or _is_file_sequence(data.get("medium")):
        from .sequence import frame_data
        data, hidden, frame = frame_data(data, frame, source, base_dir)
    if "medium" not in data:
        raise PopvolError(f"{source}: missing [medium] table")
    medium = _medium(check.table(data["medium"], "medium", source), source, Path(base_dir))
    if hidden:                                 # clipped: the frame's box, without the medium
        medium = dataclasses.replace(medium, density=np.zeros_like(medium.density))

    lights, environment = _lights(data, medium, source, base_dir)

    bg = check.table(data.get("background", {}), "background", source)
    check.known_keys(bg, _BACKGROUND_KEYS, "background.", source)
    check.choice(bg.get("type", "constant"), "background.type", source, ("constant",))
    if environment is not None and "radiance" in bg:
        raise PopvolError(f"{source}: background.radiance is given, but the background of a scene with "
                          "an environment light is the environment map itself; remove it")
    background = check.power(bg.get("radiance", 0.0), "background.radiance", source)

    method = method_from_tables(data.get("method", {}), data.get("experimental", {}), source)
    camera = _camera(data.get("camera"), medium, source)
    files = tuple(_files(data, Path(base_dir)))
    return Scene(medium, lights, camera, background, method, source, environment, files, frame, hidden)


def _lights(data: dict, medium: Medium, source: str, base_dir) -> tuple[list[Light], object]:
    """The scene's lights (an environment decomposed into its lights) and its environment (or
    None), from its ``[[lights]]`` tables, each checked against ``medium``."""
    if "lights" in data and "light" in data:
        raise PopvolError(f"{source}: both [light] and [[lights]] are given; put every light in [[lights]]")
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
        for light in got if isinstance(got, list) else [got]:
            light.check(medium)
            lights.append(light)
    return lights, environment


def check_camera_and_lights(data: dict, medium: Medium, source: str, base_dir=".") -> None:
    """Refuse, as :func:`scene_from_dict` would, the camera or lights of the plain scene data
    ``data`` (a frame's, popvol.sequence), beside ``medium`` (another frame's will do: only the
    camera's defaults and a point light's distance read it), without building the medium."""
    _lights(data, medium, source, base_dir)
    _camera(data.get("camera"), medium, source)


def _is_file_sequence(m) -> bool:
    """A medium table whose file has a run of ``#`` or that has a file sequence's keys."""
    if not isinstance(m, dict):
        return False
    return (isinstance(m.get("file"), str) and "#" in Path(m["file"]).name) or \
        any(k in m for k in ("frames", "mode", "offset"))


def _files(data, base: Path):
    """The resolved paths of every ``file = "..."`` in the scene's tables."""
    if isinstance(data, dict):
        for key, value in data.items():
            if key == "file" and isinstance(value, str):
                yield (base / value).resolve()
            else:
                yield from _files(value, base)
    elif isinstance(data, list):
        for value in data:
            yield from _files(value, base)


def _medium(m: dict, src: str, base: Path) -> Medium:
    check.known_keys(m, _MEDIUM_KEYS, "medium.", src)
    kind = check.choice(m.get("type", "file" if "file" in m else "procedural"), "medium.type", src,
                        ("procedural", "file"))
    optics = {k: m[k] for k in ("scale", "albedo", "g") if k in m}
    for key in ("albedo", "g"):              # per-voxel grids: {file = "...", grid = "..."}
        if isinstance(optics.get(key), dict):
            optics[key] = _optics_grid(optics[key], key, m, src, base)
    if kind == "procedural":
        from .procedural import DEMO_OPTICS, MOVING_STYLES, STYLES, TIME_LIMIT, demo_medium
        unused = sorted({"file", "grid", "voxel_size", "origin"} & set(m))
        if unused:
            raise PopvolError(f"{src}: medium.{unused[0]} applies to a medium read from a file, not to "
                              "medium.type = 'procedural' (whose size is medium.extent)")
        res = check.integer(m.get("resolution", 96), "medium.resolution", src, 8, 1024)
        seed = check.integer(m.get("seed", 7), "medium.seed", src, 0, 2**32 - 1)
        # voxels of at least medium.MIN_RELATIVE_VOXEL at the finest resolution, a box within
        # medium.MAX_COORDINATE
        extent = check.number(m.get("extent", 2.0), "medium.extent", src, 0.0, 1e12, open_interval=True)
        if extent < 1e-5:
            raise PopvolError(f"{src}: medium.extent = {extent:g} must be at least 1e-05 (world units; finer "
                              "voxels are lost in the rounding of world positions)")
        style = check.choice(m.get("style", STYLES[0]), "medium.style", src, STYLES)
        time = check.number(m.get("time", 0.0), "medium.time", src, -TIME_LIMIT, TIME_LIMIT)
        if time != 0 and style not in MOVING_STYLES:
            raise PopvolError(f"{src}: medium.time = {time:g} applies to medium.style = 'cumulus' or 'field' "
                              f"only (the '{style}' cloud does not move)")
        # scale 0 here: the optics, defaults included, are checked below against the scene's name
        med = demo_medium(res, seed, extent, scale=0.0, field=f"{src}: medium.resolution = {res}",
                          style=style, time=time)
        return Medium(med.density, med.voxel_size, med.origin, source=src, **{**DEMO_OPTICS, **optics})
    from .io.volumes import read_volume
    if "file" not in m:
        raise PopvolError(f"{src}: medium.type = 'file' needs medium.file")
    unused = sorted({"resolution", "seed", "extent", "style", "time"} & set(m))
    if unused:
        raise PopvolError(f"{src}: medium.{unused[0]} applies to medium.type = 'procedural', not to a "
                          "medium read from a file")
    vol = read_volume(_path(m["file"], "medium.file", src, base), _text(m.get("grid"), "medium.grid", src),
                      field=f"{src}: medium.file")
    voxel = m.get("voxel_size", vol.voxel_size)
    origin = m.get("origin", vol.origin)
    if "voxel_size" not in m or "origin" not in m:     # a value from the file: name the file
        vs = voxel if not check._is_scalar(voxel) else [voxel] * 3
        if "voxel_size" in m:
            vs = check.vector(vs, "medium.voxel_size", src, positive=True)
        else:                                    # e.g. a VDB whose transform mirrors an axis
            vs = check.vector(vs, "voxel size", vol.source, positive=True)
        check_box(vs, check.vector(origin, "medium.origin", src), vol.density.shape,
                  "medium.voxel_size" if "voxel_size" in m else f"the voxel size of {vol.source}",
                  "medium.origin" if "origin" in m else f"the origin of {vol.source}", src)
    return Medium(vol.density, voxel, origin, source=src, **_optics(None, optics))


def _optics_grid(spec: dict, key: str, m: dict, src: str, base: Path) -> np.ndarray:
    """A per-voxel albedo or g grid: ``{file = ..., grid = ...}`` (file defaults to the medium's,
    grid to the key's name). The grid must match the density's shape (checked by Medium)."""
    from .io.volumes import read_volume
    check.known_keys(spec, {"file", "grid"}, f"medium.{key}.", src)
    if "file" not in spec and "file" not in m:
        raise PopvolError(f"{src}: medium.{key} is a grid table but names no file (and the medium has none)")
    name = f"medium.{key}.file" if "file" in spec else "medium.file"
    path = _path(spec.get("file", m.get("file")), name, src, base)
    # a .vol file holds one unnamed grid; the other formats name theirs (by default the key's name)
    grid = _text(spec.get("grid", None if path.suffix.lower() == ".vol" else key), f"medium.{key}.grid", src)
    field = f"{src}: {name if 'file' in spec else f'medium.{key}'}"     # the grid the medium's file lacks
    return read_volume(path, grid, signed=(key == "g"), field=field).density


def _optics(med, given: dict) -> dict:
    out = {"scale": 1.0, "albedo": 1.0, "g": 0.0}
    if med is not None:
        out.update(scale=med.scale, albedo=med.albedo, g=med.g)
    out.update(given)
    return out


def _light(l, name: str, src: str, base: Path = Path(".")):
    """A light of the class its ``type`` names (popvol.lights.LIGHTS), or for an environment
    [EnvMap, its K directional lights]."""
    check.table(l, name, src)
    kinds = {**{kind: cls.keys for kind, cls in LIGHTS.items()}, **_ENVIRONMENT_KEYS}
    kind = check.choice(l.get("type", "directional"), f"{name}.type", src, kinds)
    check.known_keys(l, kinds[kind], f"{name}.", src)
    if kind in LIGHTS:
        return LIGHTS[kind].from_table(l, name, src)
    from . import envmap
    k = check.integer(l.get("lights", 12), f"{name}.lights", src, 1, 256)
    if kind == "envmap":
        if "file" not in l:
            raise PopvolError(f"{src}: {name}.file is required (a lat-long map, OpenEXR or Radiance .hdr)")
        env = envmap.load(_path(l["file"], f"{name}.file", src, base),
                          check.power(l.get("scale", 1.0), f"{name}.scale", src, envmap.MAX_RADIANCE),
                          field=f"{src}: {name}.scale", where=f"{src}: {name}.file: ")
    else:
        rad = lambda key, default: check.power(l.get(key, default), f"{name}.{key}", src, envmap.MAX_RADIANCE)
        env = envmap.sky(rad("zenith", [0.2, 0.35, 0.8]), rad("horizon", [0.6, 0.7, 0.9]), rad("ground", 0.0),
                         source=f"{src}: {name}")
    return [env, envmap.decompose(env, k)]


def _camera(c, medium: Medium, src: str) -> Camera:
    if c is None:
        return auto_camera(medium, source=src)
    check.table(c, "camera", src)
    check.known_keys(c, _CAMERA_KEYS, "camera.", src)
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


def _text(value, name: str, src: str) -> str | None:
    """A string (a file or grid name) of printable characters, or None when not given."""
    return None if value is None else check.text(value, name, src)


def _path(value, name: str, src: str, base: Path) -> Path:
    """A file name, relative to the scene file's folder ``base`` unless absolute."""
    p = Path(check.text(value, name, src))
    return p if p.is_absolute() else base / p


#: The built-in demo: the procedural cumulus (style "cumulus") lit by a sun from the right and
#: a little behind the camera, and by a blue sky (3 directional lights) that is also the
#: background; examples/demo.toml is the same scene written out.
DEMO_SCENE = {
    "medium": {"type": "procedural", "style": "cumulus", "resolution": 96, "seed": 7, "extent": 2.0,
               "scale": 40.0, "albedo": 0.99, "g": 0.85},
    "lights": [{"type": "directional", "direction": [-0.9, -0.4, -0.35],
                "irradiance": [5.0, 4.85, 4.5]},
               {"type": "sky", "zenith": [0.05, 0.12, 0.35], "horizon": [0.25, 0.33, 0.45],
                "ground": [0.12, 0.13, 0.15], "lights": 3}],
    "camera": {"origin": [0.0, 0.1, 2.4], "target": [0.0, 0.72, 0.0], "fov": 40.0,
               "width": 640, "height": 360},
    "method": {"resolution": 96},
}
