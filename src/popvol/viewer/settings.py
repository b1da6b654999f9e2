"""What the viewer's controls set, how a message from the page is checked, and how the settings
become a scene (to render) and a TOML table (to save).

The page sends settings as plain numbers (degrees, multipliers, stops). One rule keeps the saved
file exact: every value that goes into the view's scene is computed once as the Python float
(or list of floats) that the TOML file will hold, and the scene's objects are built from those
same values by the same constructors that :func:`popvol.scene_from_dict` calls. Loading the
saved file therefore rebuilds the very same scene, bit for bit.

Angles (degrees), with the world's +y as the sky's zenith:
- sun: ``sun_elevation`` above the horizon, ``sun_azimuth`` from +z toward +x; the sun lies
  along s = (cos el sin az, sin el, cos el cos az) and its light travels along -s.
- camera: an orbit about the scene camera's target, in a frame whose pole is the camera's
  ``up`` (for up = +y the same convention as the sun); ``camera_distance`` in world units.
"""
from __future__ import annotations

import bisect
import copy
import json
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..camera import Camera
from .. import check
from ..errors import PopvolError
from ..method import method_tables

#: Allowed range of every setting the page may send: (low, high, open interval?).
#: ``camera_distance`` is checked against the scene's own distance (see ``distance_range``).
RANGES = {
    "camera_azimuth": (-720.0, 720.0, False),
    "camera_elevation": (-89.0, 89.0, False),
    "camera_distance": (None, None, False),
    "sun_azimuth": (-720.0, 720.0, False),
    "sun_elevation": (-90.0, 90.0, False),
    "density": (0.0, 100.0, False),
    "albedo": (0.0, 1.0, False),
    "g": (-1.0, 1.0, True),
    "intensity": (0.0, 100.0, False),
    "exposure": (-16.0, 16.0, False),
}

#: Settings that change the propagated light (the rest only change the rendering).
PROPAGATION_KEYS = ("sun_azimuth", "sun_elevation", "density", "albedo", "g")

#: The frame of a sequence: an integer among the scene's frames (not a range: checked against
#: the frame list by :func:`parse_message`).
FRAME = "frame"
#: Settings that keyframes drive: a frame change resets them to the frame's own (None) when the
#: scene keyframes the camera (the first three) or the sun's direction (the last two).
CAMERA_KEYS = ("camera_azimuth", "camera_elevation", "camera_distance")
SUN_KEYS = ("sun_azimuth", "sun_elevation")


@dataclass(frozen=True)
class Settings:
    """The state of the viewer's controls; all plain floats.

    density multiplies the scene's medium scale; intensity multiplies the key light's power
    (the sun's irradiance, or without a sun the first point light's intensity); albedo and g
    replace the medium's (None: keep the scene's own, e.g. an RGB albedo or a per-voxel g);
    exposure is the PNG exposure in stops; when the scene's exposure is "auto" it is an offset
    on the auto exposure of each frame (popvol.io.images.auto_exposure), so 0 = "auto". sun_*
    are None when the scene has no sun. frame: the frame of a sequence (None for a still
    scene). In a sequence whose keyframes drive the camera or the sun, camera_* or sun_* may be
    None: "the frame's own" (``Engine.resolve`` fills them in).
    """

    camera_azimuth: float
    camera_elevation: float
    camera_distance: float
    sun_azimuth: float | None
    sun_elevation: float | None
    density: float = 1.0
    albedo: float | None = None
    g: float | None = None
    intensity: float = 1.0
    exposure: float = 0.0
    frame: int | None = None

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def propagation_key(self) -> tuple:
        """What the propagated light depends on (not camera, intensity or exposure)."""
        return tuple(getattr(self, k) for k in PROPAGATION_KEYS)


# ---------------------------------------------------------------------------------------------
# Messages from the page
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Message:
    """A checked message: kind "set" (with the changed settings) or "save"."""

    kind: str
    changes: dict


def parse_message(text, distance_range: tuple[float, float], has_sun: bool, has_key: bool = True,
                  frames: list[int] | None = None) -> Message:
    """Check one websocket message from the page; raise a one-line PopvolError if it is bad.

    Accepted: ``{"type": "set", "settings": {name: number, ...}}`` (names and ranges in
    RANGES, and ``frame``) and ``{"type": "save"}``. has_sun / has_key: whether the scene has a
    sun to move and a light whose intensity the page may change. frames: the sequence's frames
    (increasing), which ``frame`` must be one of; None for a still scene, which refuses it.
    """
    if not isinstance(text, str):
        raise PopvolError("messages must be JSON text, got binary data")
    try:
        msg = json.loads(text, parse_constant=_no_constant)
    except RecursionError:
        raise PopvolError("message is nested too deeply") from None
    except ValueError as e:          # invalid JSON, or an integer of more than 4300 digits
        raise PopvolError(f"message is not valid JSON ({_one_line(e)})") from None
    if not isinstance(msg, dict):
        raise PopvolError(f"message must be a JSON object, got {type(msg).__name__}")
    kind = msg.get("type")
    if kind == "save":
        _only_keys(msg, {"type"}, "save message")
        return Message("save", {})
    if kind != "set":
        raise PopvolError(f"message type {check._show(kind)} is unknown (known: 'set', 'save')")
    _only_keys(msg, {"type", "settings"}, "set message")
    changes = msg.get("settings")
    if not isinstance(changes, dict) or not changes:
        raise PopvolError("set message needs a non-empty object 'settings'")
    out = {}
    for name, value in changes.items():
        if name == FRAME:
            out[name] = check_frame(value, frames)
            continue
        if name not in RANGES:
            raise PopvolError(f"unknown setting {check._show(name)} (known: {', '.join(RANGES)}, {FRAME})")
        if name.startswith("sun_") and not has_sun:
            raise PopvolError(f"setting {check._show(name)}: this scene has no directional light to move")
        if name == "intensity" and not has_key:
            raise PopvolError("setting 'intensity': this scene has no sun or point light (only an environment)")
        lo, hi, open_ = RANGES[name]
        if name == "camera_distance":
            lo, hi = distance_range
        out[name] = check.number(value, name, "set message", lo, hi, open_)
    return Message("set", out)


def check_frame(value, frames: list[int] | None, src: str = "set message") -> int:
    """``value`` as one of ``frames`` (increasing frame numbers; None: a still scene, which has
    no frames); a one-line PopvolError otherwise. Integral floats (12.0) are taken as integers."""
    if frames is None:
        raise PopvolError("setting 'frame': this scene has no frames (no [sequence], medium file "
                          "sequence or [[keyframes]]); it is a still scene")
    from ..sequence import frames_text
    n = None
    if check._is_int(value):
        n = int(value)
    elif check._is_real(value) and math.isfinite(value) and float(value).is_integer():
        n = int(value)
    i = bisect.bisect_left(frames, n) if n is not None else 0
    if n is None or i == len(frames) or frames[i] != n:
        raise PopvolError(f"{src}: frame = {check._show(value)} must be one of the scene's frames "
                          f"({frames_text(frames)})")
    return n


def _one_line(e: Exception, limit: int = 200) -> str:
    text = " ".join(str(e).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _no_constant(name):
    raise ValueError(f"{name} is not a number JSON allows")


def _only_keys(msg: dict, known: set, what: str):
    extra = sorted(set(msg) - known)
    if extra:
        shown = ", ".join(map(check._show, extra[:5])) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        raise PopvolError(f"{what} has unknown key(s) {shown}")


# ---------------------------------------------------------------------------------------------
# Angles <-> vectors
# ---------------------------------------------------------------------------------------------

def orbit_frame(up) -> np.ndarray:
    """float64 (3, 3): rows e1 (azimuth 0), e2 (azimuth 90), u (the pole = unit up)."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    ref = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = ref - u * (ref @ u)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1), u])


def angles_of(v, frame: np.ndarray) -> tuple[float, float]:
    """(azimuth, elevation) in degrees of the direction ``v`` (3,) in ``frame`` (orbit_frame)."""
    a, b, c = frame @ (np.asarray(v, np.float64) / np.linalg.norm(v))
    return math.degrees(math.atan2(b, a)), math.degrees(math.asin(max(-1.0, min(1.0, c))))


def direction_of(azimuth: float, elevation: float, frame: np.ndarray) -> np.ndarray:
    """Unit vector float64 (3,) at (azimuth, elevation) degrees in ``frame``."""
    az, el = math.radians(azimuth), math.radians(elevation)
    return frame.T @ np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


SKY = orbit_frame((0.0, 1.0, 0.0))        # the sun's frame: e1 = +z, e2 = +x, pole +y


def _floats(a) -> list[float]:
    return [float(x) for x in np.asarray(a, np.float64).ravel()]


# ---------------------------------------------------------------------------------------------
# Settings -> scene values -> scene objects and TOML
# ---------------------------------------------------------------------------------------------

def sun_index(scene) -> int | None:
    """Index in scene.lights of the light the sun control moves: the first directional light
    that does not come from an environment map (None if there is none)."""
    return next((i for i, light in enumerate(scene.lights)
                 if light.type == "directional" and not light.from_environment), None)


def key_index(scene) -> int | None:
    """Index in scene.lights of the light the intensity control scales: the sun, or else the
    first light that is not part of an environment (None if there is none)."""
    i = sun_index(scene)
    if i is None:
        i = next((j for j, light in enumerate(scene.lights) if not light.from_environment), None)
    return i


def key_entry(data: dict, scene) -> int | None:
    """Index in the TOML's [[lights]] list of that same light (None if there is none)."""
    i = key_index(scene)
    if i is None:
        return None
    kind = scene.lights[i].type
    for i, entry in enumerate(_light_list(data)):
        if isinstance(entry, dict) and entry.get("type", "directional") == kind:
            return i
    return None


def _light_list(data: dict) -> list:
    lights = data.get("lights", data.get("light", []))
    return [lights] if isinstance(lights, dict) else list(lights)


def scene_angles(scene) -> dict:
    """The camera's orbit (camera_azimuth, camera_elevation, camera_distance) and the sun's
    angles (sun_azimuth, sun_elevation; None without a sun) of ``scene``, as the controls hold
    them."""
    cam = scene.camera
    az, el = angles_of(cam.origin - cam.target, orbit_frame(cam.up))
    sun_az = sun_el = None
    i = sun_index(scene)
    if i is not None:
        sun_az, sun_el = angles_of(-scene.lights[i].direction, SKY)
    return {"camera_azimuth": az, "camera_elevation": max(-89.0, min(89.0, el)),
            "camera_distance": float(np.linalg.norm(cam.origin - cam.target)),
            "sun_azimuth": sun_az, "sun_elevation": sun_el}


def initial_settings(scene) -> Settings:
    """The controls' starting state: the scene as loaded (its ``frame`` for a sequence)."""
    med = scene.medium
    albedo = float(med.albedo[0]) if not med.albedo_per_voxel and np.ptp(med.albedo) == 0 else None
    g = None if med.g_per_voxel else float(med.g)
    return Settings(**scene_angles(scene), density=1.0, albedo=albedo, g=g, intensity=1.0,
                    exposure=_exposure_setting(scene.method.exposure), frame=scene.frame)


def _exposure_setting(exposure) -> float:
    """The exposure control's start: the scene's stops, or offset 0 on "auto"."""
    return 0.0 if isinstance(exposure, str) else float(exposure)


def scene_values(base, s: Settings, width: int, height: int) -> dict:
    """The TOML values of the view: ``{"medium": {...}, "key": {...} or None, "camera": {...}}``,
    plain floats and lists, computed from the base scene (as loaded) and the settings. "key"
    holds the key light's table with its power scaled and, for the sun, its new direction."""
    med = base.medium
    medium = {"scale": _grey_or_rgb(np.asarray(med.scale) * s.density)}
    if s.albedo is not None:
        medium["albedo"] = s.albedo
    if s.g is not None:
        medium["g"] = s.g
    key = None
    i = key_index(base)
    if i is not None:
        key = base.lights[i].scaled(s.intensity).table()
        del key["type"]
        if i == sun_index(base):
            key["direction"] = _floats(-direction_of(s.sun_azimuth, s.sun_elevation, SKY))
    cam = base.camera
    offset = s.camera_distance * direction_of(s.camera_azimuth, s.camera_elevation, orbit_frame(cam.up))
    camera = {"origin": _floats(cam.target + offset), "target": _floats(cam.target),
              "up": _floats(cam.up), "fov": float(cam.fov), "width": int(width), "height": int(height)}
    return {"medium": medium, "key": key, "camera": camera}


def _grey_or_rgb(v: np.ndarray):
    v = _floats(v)
    return v[0] if v[0] == v[1] == v[2] else v


def build_medium(base_medium, values: dict):
    """The view's Medium: the base medium (its density array shared, so solve's reuse sees the
    same grid) with the scale/albedo/g of ``values["medium"]``."""
    return replace(base_medium, **values["medium"])


def build_scene(base, values: dict, medium, method):
    """The view's Scene from the base scene, the scene values, a Medium and a Method."""
    lights = list(base.lights)
    key = values["key"]
    if key is not None:
        i = key_index(base)
        lights[i] = replace(lights[i], **key)
    c = values["camera"]
    camera = Camera(c["origin"], c["target"], c["up"], c["fov"], c["width"], c["height"], source=base.camera.source)
    return replace(base, medium=medium, lights=lights, camera=camera, method=method)


def scene_toml(data: dict, base_dir: Path, values: dict, method, base) -> dict:
    """The scene file of the view: the loaded TOML ``data`` with the view's values, every method
    field written out, and file paths made absolute (so the file renders from any folder)."""
    out = copy.deepcopy(data)
    if "light" in out:                       # the loader also accepts [light]; write [[lights]]
        out["lights"] = _light_list(out)
        del out["light"]
    medium = out.setdefault("medium", {})
    _absolute(medium, "file", base_dir)
    for key in ("albedo", "g"):
        if isinstance(medium.get(key), dict):
            _absolute(medium[key], "file", base_dir)
    medium.update(values["medium"])
    for entry in out.get("lights", []):
        if isinstance(entry, dict):
            _absolute(entry, "file", base_dir)
    if values["key"] is not None:
        out["lights"][key_entry(out, base)].update(values["key"])
    out["camera"] = dict(values["camera"])
    out.pop("experimental", None)
    tables = method_tables(method)
    out["method"] = tables["method"]
    if tables["experimental"]:
        out["experimental"] = tables["experimental"]
    return out


def _absolute(table: dict, key: str, base_dir: Path):
    if isinstance(table.get(key), str):
        p = Path(table[key])
        table[key] = str(p if p.is_absolute() else (base_dir / p).resolve())
