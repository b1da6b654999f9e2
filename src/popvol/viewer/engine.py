"""The viewer's renderer: turns settings into frames, propagating only when it must.

- A camera or exposure change renders with the solution it has (no propagation).
- The PNG uses the scene's tone curve; with the scene's exposure "auto" the exposure control is
  an offset on each frame's auto exposure, and Save writes the stops the saved view used.
- An intensity change replaces the solution's irradiance (fields are per unit power).
- A sun or medium change propagates again; ``popvol.solve(reuse=...)`` copies
  the domains of lights that did not change from the previous solution.

Two levels of quality: "draft" (while the user drags: half the pixels per axis, a coarser
ray-marching step, and, if no full solution is at hand, a coarser propagation grid) and "full"
(the view's own method and size, what Save writes and ``popvol render`` reproduces).

An Engine is not thread-safe: the server calls it from one worker thread only.
"""
from __future__ import annotations

import copy
import io
import time
import tomllib
from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import PopvolError
from ..io.images import auto_exposure, tonemap, write_image
from ..pipeline import solve
from ..renderer import render
from ..scene import DEMO_SCENE, load_scene
from . import settings as S

DRAFT, FULL = "draft", "full"
MAX_SOLUTIONS = 4                  # solutions kept for returning to earlier settings ...
MAX_CACHE_BYTES = 512 * 2**20      # ... as long as their fields fit in this many bytes


@dataclass
class Frame:
    """One rendered view.

    image: float32 (height, width, 3) linear HDR radiance; png: the tone-mapped PNG (exposure
    applied); seconds: wall time of propagate (0 when the solution was at hand), render and
    encode; resolution: propagation cells of the solution used; exposure: the stops the PNG
    was made with (the control's, plus the auto exposure when the scene's is "auto").
    """

    image: np.ndarray
    png: bytes
    level: str
    settings: S.Settings
    seconds: dict
    propagated: bool
    resolution: int
    exposure: float = 0.0

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def height(self) -> int:
        return self.image.shape[0]


def view_method(method, resolution: int, **changes):
    """``method`` at ``resolution`` cells (never more than its own): the diffusion and
    environment grids shrink by the same factor, so their ratios to the domain stay the scene's."""
    f = min(1.0, resolution / method.resolution)
    out = replace(method, resolution=max(2, round(method.resolution * f)), **changes)
    if method.diffusion_resolution:
        out.diffusion_resolution = max(2, round(method.diffusion_resolution * f))
    if method.environment_resolution:
        out.environment_resolution = max(2, round(method.environment_resolution * f))
    return out


class Engine:
    """Frames of one scene under changing settings.

    path: the scene TOML (None: the built-in demo). width, height: the full view size (default
    the scene's camera). resolution: cells of the view's propagation domains (at most the
    scene's; the saved TOML keeps it). draft_resolution, draft_scale, draft_step: the draft's
    propagation cells, fraction of the pixels per axis and ray-marching step multiplier.
    """

    def __init__(self, path=None, width: int | None = None, height: int | None = None,
                 resolution: int = 64, draft_resolution: int = 32, draft_scale: float = 0.5,
                 draft_step: float = 2.0):
        self.base = load_scene(path, width=width, height=height)
        if path is None:
            self.data, self.base_dir = copy.deepcopy(DEMO_SCENE), Path.cwd()
        else:
            self.data, self.base_dir = tomllib.loads(Path(path).read_text()), Path(path).resolve().parent
        for name, v in (("--resolution", resolution), ("--draft-resolution", draft_resolution)):
            if isinstance(v, bool) or not isinstance(v, int) or not 2 <= v <= 4096:
                raise PopvolError(f"{name} = {v!r} must be an integer in [2, 4096]")
        self.method = view_method(self.base.method, resolution)
        self.draft_method = view_method(self.base.method, min(draft_resolution, self.method.resolution),
                                        spp=1, step=min(16.0, self.base.method.step * draft_step))
        cam = self.base.camera
        self.size = {FULL: (cam.width, cam.height),
                     DRAFT: (max(1, round(cam.width * draft_scale)), max(1, round(cam.height * draft_scale)))}
        self.exposure_auto = self.base.method.exposure == "auto"
        self.tone = self.base.method.tone
        self.initial = S.initial_settings(self.base)
        d0 = self.initial.camera_distance
        self.distance_range = (d0 / 100.0, d0 * 100.0)
        self.has_sun = S.sun_index(self.base) is not None
        self.has_key = S.key_index(self.base) is not None
        self._media = OrderedDict()         # medium values -> Medium (the last few)
        self._solutions = OrderedDict()     # (propagation key, resolution) -> Solution
        self._last = {}                     # resolution -> the last solution solved at it (reuse)
        self.solves = 0                     # propagations run (counted for tests and the page)
        self.renders = 0
        self.last_full: Frame | None = None

    # -- frames --------------------------------------------------------------------------------

    def scene_for(self, settings: S.Settings, level: str = FULL):
        """The Scene the view renders at ``level`` (camera size and method of that level)."""
        w, h = self.size[level]
        values = S.scene_values(self.base, settings, w, h)
        method = self.method if level == FULL else self.draft_method
        exposure = "auto" if self.exposure_auto else settings.exposure
        return S.build_scene(self.base, values, self._medium(values), replace(method, exposure=exposure))

    def exposure_of(self, settings: S.Settings, image: np.ndarray) -> float:
        """The stops the PNG of ``image`` is made with: the control's, plus the auto exposure of
        ``image`` when the scene's exposure is "auto"."""
        if self.exposure_auto:
            return settings.exposure + auto_exposure(image, tone=self.tone)
        return settings.exposure

    def frame(self, settings: S.Settings, level: str = FULL) -> Frame:
        """Render ``settings`` at ``level``, propagating only if no valid solution is at hand."""
        t0 = time.perf_counter()
        scene = self.scene_for(settings, level)
        solution, propagated, res = self._solution(scene, settings, level)
        t1 = time.perf_counter()
        image = render(scene, solution)
        self.renders += 1
        t2 = time.perf_counter()
        exposure = self.exposure_of(settings, image)
        png = encode_png(image, exposure, self.tone)
        t3 = time.perf_counter()
        f = Frame(image, png, level, settings, {"propagate": t1 - t0 if propagated else 0.0,
                                                 "render": t2 - t1, "encode": t3 - t2}, propagated, res,
                  exposure)
        if level == FULL:
            self.last_full = f
        return f

    def _medium(self, values: dict):
        key = repr(values["medium"])
        if key not in self._media:
            self._media[key] = S.build_medium(self.base.medium, values)
            while len(self._media) > 4:
                self._media.popitem(last=False)
        self._media.move_to_end(key)
        return self._media[key]

    def _solution(self, scene, settings: S.Settings, level: str):
        """(solution with the scene's irradiance, whether it was propagated now, its cells)."""
        full_key = (settings.propagation_key(), self.method.resolution)
        keys = [full_key] if level == FULL else [full_key, (settings.propagation_key(), self.draft_method.resolution)]
        for key in keys:
            if key in self._solutions:
                self._solutions.move_to_end(key)
                return self._solutions[key].relit(scene.lights), False, key[1]
        key = keys[-1]                      # the scene's own method has this level's cells
        previous = self._last.get(key[1])
        sol = solve(scene, reuse=previous)
        self.solves += 1
        self._last[key[1]] = sol
        self._solutions[key] = sol
        while len(self._solutions) > 1 and (len(self._solutions) > MAX_SOLUTIONS or sum(
                x.nbytes for x in self._solutions.values()) > MAX_CACHE_BYTES):
            self._solutions.popitem(last=False)
        return sol, True, key[1]

    # -- saving --------------------------------------------------------------------------------

    def toml_data(self, settings: S.Settings) -> dict:
        """The scene file (as a dict) that ``popvol render`` turns into the full view (its
        exposure: the stops of the full frame, see :meth:`exposure_of`)."""
        w, h = self.size[FULL]
        values = S.scene_values(self.base, settings, w, h)
        exposure = self._full_frame(settings).exposure if self.exposure_auto else settings.exposure
        return S.scene_toml(self.data, self.base_dir, values, replace(self.method, exposure=exposure),
                            self.base)

    def _full_frame(self, settings: S.Settings) -> Frame:
        f = self.last_full
        return f if f is not None and f.settings == settings else self.frame(settings, FULL)

    def save(self, settings: S.Settings, folder) -> tuple[Path, Path]:
        """Write the full view as PNG and its scene as TOML in ``folder`` under the first free
        name popvol-view-NNN; returns (png path, toml path)."""
        import tomli_w
        folder = Path(folder)
        if not folder.is_dir():
            raise PopvolError(f"save folder {folder} does not exist")
        f = self._full_frame(settings)
        for n in range(1, 100_000):
            png, toml = folder / f"popvol-view-{n:03d}.png", folder / f"popvol-view-{n:03d}.toml"
            if not png.exists() and not toml.exists():
                break
        else:
            raise PopvolError(f"save folder {folder} already holds 99999 saved views")
        header = ("# Saved by `popvol view`; `popvol render THIS.toml -o view.png` renders the view again.\n"
                  f"# Scene: {self.base.source}\n\n")
        try:
            toml.write_text(header + tomli_w.dumps(self.toml_data(settings)))
        except OSError as e:
            raise PopvolError(f"{toml}: cannot write ({e})") from None
        write_image(png, f.image, f.exposure, self.tone)
        return png, toml


def encode_png(image: np.ndarray, exposure, tone: str = "aces") -> bytes:
    """PNG bytes of the tone-mapped float32 (H, W, 3) ``image`` (``exposure`` in stops or
    "auto", ``tone``; fast compression: the pixels are those ``popvol.write_image`` writes)."""
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(tonemap(image, exposure, tone), "RGB").save(buf, format="PNG", compress_level=1)
    return buf.getvalue()
