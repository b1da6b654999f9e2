"""The viewer's renderer: turns settings into frames, propagating only when it must.

- A camera or exposure change renders with the solution it has (no propagation).
- The PNG uses the scene's tone curve; with the scene's exposure "auto" the exposure control is
  an offset on each frame's auto exposure, and Save writes the stops the saved view used.
- An intensity change replaces the solution's irradiance (fields are per unit power).
- A sun or medium change propagates again; ``popvol.solve(reuse=...)`` copies
  the domains of lights that did not change from the previous solution.

Three levels of quality, each refining the one before once input stops (:meth:`Engine.next_level`):
- "draft" while the user drags: half the pixels per axis, a coarser ray-marching step, no
  gathered last bounce, and, if no full solution is at hand, a coarser propagation grid;
- "preview": the view's own size and propagation, without the gathered last bounce (skipped
  where the method does not gather): a sun move fully propagated and shown at once;
- "full": the view's own method and size, gathered last bounce included: what Save writes and
  ``popvol render`` reproduces. It renders from the preview's solution.

A sequence (docs/SCENE.md, "Sequences") adds the ``frame`` setting: each frame's scene (its
medium, keyframed lights and camera) is loaded by :mod:`popvol.sequence` and the last few are
kept (:data:`MAX_FRAMES`, :data:`MAX_FRAME_BYTES`); the controls apply on top of it. Where the
keyframes drive the camera or the sun, a setting of None means "the frame's own" (see
:meth:`Engine.resolve`). A draft whose frame changed from the last solve (and nothing else that
propagation depends on) is warm-started from that solution where ``popvol.solve`` takes
``warm``; full frames are always solved cold, so they are bit for bit what ``popvol render``
makes of the saved scene.

An Engine is not thread-safe: the server calls it from one worker thread only.
"""
from __future__ import annotations

import copy
import inspect
import io
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import PopvolError
from ..io.images import auto_exposure, image_writer, tonemap, write_together
from ..pipeline import solve
from ..renderer import render
from ..scene import DEMO_SCENE, load_scene, read_scene_file
from ..sequence import frames_text, load_sequence
from . import settings as S

DRAFT, PREVIEW, FULL = "draft", "preview", "full"
MAX_SOLUTIONS = 4                  # solutions kept for returning to earlier settings ...
MAX_CACHE_BYTES = 512 * 2**20      # ... as long as their fields fit in this many bytes
MAX_FRAMES = 8                     # frames' scenes (loaded media) kept for scrubbing back ...
MAX_FRAME_BYTES = 256 * 2**20      # ... as long as their media's grids fit in this many bytes


@dataclass
class Frame:
    """One rendered view.

    image: float32 (height, width, 3) linear HDR radiance; png: the tone-mapped PNG (exposure
    applied); seconds: wall time of load (building the view's scene, a sequence's frame loaded
    from its files or generated), propagate (0 when the solution was at hand), render and
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
    """``method`` at ``resolution`` cells (never more than its own): the diffusion, environment
    and gather grids shrink by the same factor, so their ratios to the domain stay the scene's."""
    f = min(1.0, resolution / method.resolution)
    out = replace(method, resolution=max(2, round(method.resolution * f)), **changes)
    for name in ("diffusion_resolution", "environment_resolution", "gather_resolution"):
        if getattr(method, name):
            setattr(out, name, max(2, round(getattr(method, name) * f)))
    return out


class Engine:
    """Frames of one scene under changing settings.

    path: the scene TOML (None: the built-in demo). width, height: the full view size (default
    the scene's camera). resolution: cells of the view's propagation domains (at most the
    scene's; the saved TOML keeps it). draft_resolution, draft_scale, draft_step: the draft's
    propagation cells, fraction of the pixels per axis and ray-marching step multiplier.

    A sequence starts at its first frame; ``frames`` lists its frames (None: a still scene),
    ``follows`` the settings its keyframes drive (reset to the frame's own on a frame change).
    """

    def __init__(self, path=None, width: int | None = None, height: int | None = None,
                 resolution: int = 64, draft_resolution: int = 32, draft_scale: float = 0.5,
                 draft_step: float = 2.0):
        self.overrides = {k: v for k, v in (("width", width), ("height", height)) if v is not None}
        self.sequence = load_sequence(path)
        self.frames = self.sequence.frames if self.sequence.animated else None
        if self.frames is not None:
            self.sequence.check_files(self.frames)          # every missing file named now, not mid-play
        self.base = load_scene(path, frame=None if self.frames is None else self.frames[0], **self.overrides)
        if path is None:
            self.data, self.base_dir = copy.deepcopy(DEMO_SCENE), Path.cwd()
        else:
            self.data, self.base_dir = read_scene_file(path), Path(path).resolve().parent
        for name, v in (("--resolution", resolution), ("--draft-resolution", draft_resolution)):
            if isinstance(v, bool) or not isinstance(v, int) or not 2 <= v <= 4096:
                raise PopvolError(f"{name} = {v!r} must be an integer in [2, 4096]")
        self.method = view_method(self.base.method, resolution)
        self.draft_method = view_method(self.base.method, min(draft_resolution, self.method.resolution),
                                        spp=1, step=min(16.0, self.base.method.step * draft_step), gather=0)
        self.preview_method = replace(self.method, gather=0)
        cam = self.base.camera
        self.size = {FULL: (cam.width, cam.height), PREVIEW: (cam.width, cam.height),
                     DRAFT: (max(1, round(cam.width * draft_scale)), max(1, round(cam.height * draft_scale)))}
        self.exposure_auto = self.base.method.exposure == "auto"
        self.tone = self.base.method.tone
        self.initial = replace(S.initial_settings(self.base), frame=self.base.frame if self.frames else None)
        d0 = self.initial.camera_distance
        self.distance_range = (d0 / 100.0, d0 * 100.0)
        self.has_sun = S.sun_index(self.base) is not None
        self.has_key = S.key_index(self.base) is not None
        self.follows = self._followed_keys()
        self.warm_start = "warm" in inspect.signature(solve).parameters
        self._frames = OrderedDict()        # frame data -> (Scene, medium token) (the last few)
        if self.frames is not None:
            self._frames[self._frame_key(self.frames[0])] = (self.base, self._medium_token(self.frames[0]))
        self._media = OrderedDict()         # (medium token, medium values) -> Medium (the last few)
        self._solutions = OrderedDict()     # (propagation key, resolution) -> Solution
        self._last = {}                     # resolution -> (the last solution solved at it, its frame, key)
        self._stops = None                  # a sequence's held auto exposure (see exposure_of)
        self.solves = 0                     # propagations run (counted for tests and the page)
        self.warm_solves = 0                # of which warm-started from the previous frame's
        self.renders = 0
        self.last_full: Frame | None = None

    # -- sequences -----------------------------------------------------------------------------

    def _followed_keys(self) -> tuple:
        """The settings the keyframes drive: the camera's orbit if any keyframe sets a camera
        field, the sun's angles if any keyframe sets the sun's direction."""
        if self.frames is None:
            return ()
        keyed = {key for kf in self.sequence.keyframes for key in kf.values}
        out = ()
        if any(owner == "camera" for owner, _ in keyed):
            out += S.CAMERA_KEYS
        if self.has_sun and ((("lights", S.key_entry(self.data, self.base)), "direction") in keyed):
            out += S.SUN_KEYS
        return out

    def _frame_key(self, frame: int) -> str:
        data, hidden = self.sequence.frame_data(frame)
        return repr((data, hidden))

    def _medium_token(self, frame: int) -> str:
        """What a frame's medium is made of (frames with the same token share one Medium)."""
        data, hidden = self.sequence.frame_data(frame)
        return repr((data.get("medium"), hidden))

    def frame_scene(self, frame: int | None):
        """(the Scene of ``frame`` as loaded, its medium token); the still scene for None.
        The last few frames' scenes are kept (their media are the memory: MAX_FRAMES,
        MAX_FRAME_BYTES); frames whose medium is made of the same data share one Medium."""
        if self.frames is None:
            if frame is not None:
                raise PopvolError("setting 'frame': this scene has no frames; it is a still scene")
            return self.base, "still"
        S.check_frame(frame, self.frames, "frame")
        key = self._frame_key(frame)
        if key in self._frames:
            self._frames.move_to_end(key)
            return self._frames[key]
        token = self._medium_token(frame)
        scene = self.sequence.scene(frame, **self.overrides)
        for other, other_token in self._frames.values():
            if other_token == token:        # the same medium: share it (and solve's reuse sees it)
                scene.medium = other.medium
                break
        self._frames[key] = (scene, token)
        while len(self._frames) > 1 and (len(self._frames) > MAX_FRAMES or sum(
                _medium_bytes(m) for m in {id(sc.medium): sc.medium for sc, _ in self._frames.values()}.values())
                > MAX_FRAME_BYTES):
            self._frames.popitem(last=False)
        return scene, token

    def resolve(self, settings: S.Settings) -> S.Settings:
        """``settings`` with the frame filled in (a sequence's first for None) and every setting
        that is None because keyframes drive it (camera orbit, sun angles) set to the frame's own."""
        frame = settings.frame
        if self.frames is not None and frame is None:
            frame = self.frames[0]
        missing = [k for k in self.follows if getattr(settings, k) is None]
        if not missing:
            return settings if frame == settings.frame else replace(settings, frame=frame)
        angles = S.scene_angles(self.frame_scene(frame)[0])
        return replace(settings, frame=frame, **{k: angles[k] for k in missing})

    def frames_info(self) -> dict | None:
        """The sequence's frames for the page: first, last, step (the smallest spacing), count,
        runs ([start, stop, step], every member of an arithmetic run), text and fps; None for a
        still scene."""
        if self.frames is None:
            return None
        f = self.frames
        runs, i = [], 0
        while i < len(f):
            j, step = i, (f[i + 1] - f[i] if i + 1 < len(f) else 1)
            while j + 1 < len(f) and f[j + 1] - f[j] == step:
                j += 1
            runs.append([f[i], f[j], step])
            i = j + 1
        steps = [b - a for a, b in zip(f, f[1:])]
        return {"first": f[0], "last": f[-1], "step": min(steps) if steps else 1, "count": len(f),
                "runs": runs, "text": frames_text(f), "fps": self.sequence.fps}

    # -- frames --------------------------------------------------------------------------------

    def scene_for(self, settings: S.Settings, level: str = FULL):
        """The Scene the view renders at ``level`` (camera size and method of that level)."""
        return self._scene_for(self.resolve(settings), level)[0]

    def _scene_for(self, settings: S.Settings, level: str):
        """(Scene, medium token) of resolved ``settings`` at ``level``."""
        base, token = self.frame_scene(settings.frame)
        w, h = self.size[level]
        values = S.scene_values(base, settings, w, h)
        method = {FULL: self.method, PREVIEW: self.preview_method, DRAFT: self.draft_method}[level]
        exposure = "auto" if self.exposure_auto else settings.exposure
        medium = self._medium(base.medium, token, values)
        return S.build_scene(base, values, medium, replace(method, exposure=exposure)), token

    def exposure_of(self, settings: S.Settings, image: np.ndarray, level: str = FULL) -> float:
        """The stops the PNG of ``image`` is made with: the control's, plus the auto exposure of
        ``image`` when the scene's exposure is "auto". A sequence holds one auto exposure for
        every frame (as ``popvol render`` does, so playing does not pump): the first full
        frame's, metered when it is rendered (drafts before it meter themselves)."""
        if not self.exposure_auto:
            return settings.exposure
        if self.frames is None:
            return settings.exposure + auto_exposure(image, tone=self.tone)
        if self._stops is None:
            stops = auto_exposure(image, tone=self.tone)
            if level != FULL:
                return settings.exposure + stops
            self._stops = stops
        return settings.exposure + self._stops

    def next_level(self, level: str) -> str | None:
        """The level that refines a frame at ``level`` once input stops (None after "full"):
        draft -> preview -> full, or draft -> full where the view's method does not gather."""
        if level == DRAFT:
            return PREVIEW if self.method.gather > 0 else FULL
        return FULL if level == PREVIEW else None

    def frame(self, settings: S.Settings, level: str = FULL) -> Frame:
        """Render ``settings`` at ``level``, propagating only if no valid solution is at hand.
        The Frame holds the resolved settings (frame and keyframe-driven values filled in)."""
        t0 = time.perf_counter()
        settings = self.resolve(settings)
        scene, token = self._scene_for(settings, level)
        tl = time.perf_counter()
        solution, propagated, res = self._solution(scene, settings, level, token)
        t1 = time.perf_counter()
        image = render(scene, solution)
        self.renders += 1
        t2 = time.perf_counter()
        exposure = self.exposure_of(settings, image, level)
        png = encode_png(image, exposure, self.tone)
        t3 = time.perf_counter()
        f = Frame(image, png, level, settings, {"load": tl - t0, "propagate": t1 - tl if propagated else 0.0,
                                                 "render": t2 - t1, "encode": t3 - t2}, propagated, res,
                  exposure)
        if level == FULL:
            self.last_full = f
        return f

    def _medium(self, base_medium, token: str, values: dict):
        key = (token, repr(values["medium"]))
        if key not in self._media:
            self._media[key] = S.build_medium(base_medium, values)
            while len(self._media) > 4:
                self._media.popitem(last=False)
        self._media.move_to_end(key)
        return self._media[key]

    def _solution(self, scene, settings: S.Settings, level: str, token: str = "still"):
        """(solution with the scene's irradiance, whether it was propagated now, its cells).

        Keyed by what propagation depends on: the frame's medium, the settings of the medium and
        the sun, and every light's key (keyframed lights differ between frames)."""
        pkey = (token, settings.propagation_key(), tuple(light.key() for light in scene.lights))
        full_key = (pkey, self.method.resolution)
        keys = [full_key] if level != DRAFT else [full_key, (pkey, self.draft_method.resolution)]
        for key in keys:
            if key in self._solutions:
                self._solutions.move_to_end(key)
                return self._solutions[key].relit(scene.lights), False, key[1]
        key = keys[-1]                      # the scene's own method has this level's cells
        previous, prev_frame, prev_user = self._last.get(key[1], (None, None, None))
        user = self._user_key(settings)
        kw = {}
        if (level == DRAFT and self.warm_start and previous is not None and prev_frame != settings.frame
                and prev_user == user):     # only the frame changed: start from the previous frame
            kw["warm"] = previous
            self.warm_solves += 1
        sol = solve(scene, reuse=previous, **kw)
        self.solves += 1
        self._last[key[1]] = (sol, settings.frame, user)
        self._solutions[key] = sol
        while len(self._solutions) > 1 and (len(self._solutions) > MAX_SOLUTIONS or sum(
                x.nbytes for x in self._solutions.values()) > MAX_CACHE_BYTES):
            self._solutions.popitem(last=False)
        return sol, True, key[1]

    def _user_key(self, settings: S.Settings) -> tuple:
        """The settings propagation depends on that the user sets (not the keyframes)."""
        return tuple(None if k in self.follows else getattr(settings, k) for k in S.PROPAGATION_KEYS)

    # -- saving --------------------------------------------------------------------------------

    def toml_data(self, settings: S.Settings) -> dict:
        """The scene file (as a dict) that ``popvol render`` turns into the full view (its
        exposure: the stops of the full frame, see :meth:`exposure_of`). For a sequence, a still
        scene of the current frame: the frame's own data (its medium file, procedural time,
        keyframed lights and camera; no [sequence] or [[keyframes]]) with the view's values."""
        settings = self.resolve(settings)
        base, _ = self.frame_scene(settings.frame)
        w, h = self.size[FULL]
        values = S.scene_values(base, settings, w, h)
        exposure = self._full_frame(settings).exposure if self.exposure_auto else settings.exposure
        data = self.data
        if self.frames is not None:
            data, hidden = self.sequence.frame_data(settings.frame)
            if hidden:                      # clipped away: the nearest file's box, with no extinction
                values["medium"]["scale"] = 0.0
        return S.scene_toml(data, self.base_dir, values, replace(self.method, exposure=exposure), base)

    def _full_frame(self, settings: S.Settings) -> Frame:
        settings = self.resolve(settings)
        f = self.last_full
        return f if f is not None and f.settings == settings else self.frame(settings, FULL)

    def save(self, settings: S.Settings, folder) -> tuple[Path, Path]:
        """Write the full view as PNG and its scene as TOML in ``folder`` under the first free
        name popvol-view-NNN; returns (png path, toml path)."""
        import tomli_w
        from ..io.files import folder_problem
        folder = Path(folder)
        if problem := folder_problem(folder):
            raise PopvolError(f"save folder {folder} {problem}")
        f = self._full_frame(settings)
        for n in range(1, 100_000):
            png, toml = folder / f"popvol-view-{n:03d}.png", folder / f"popvol-view-{n:03d}.toml"
            if not png.exists() and not toml.exists():
                break
        else:
            raise PopvolError(f"save folder {folder} already holds 99999 saved views")
        settings = self.resolve(settings)
        of = "" if self.frames is None else f", frame {settings.frame} (a still scene of that frame)"
        header = ("# Saved by `popvol view`; `popvol render THIS.toml -o view.png` renders the view again.\n"
                  f"# Scene: {self.base.source}{of}\n\n")
        text = header + tomli_w.dumps(self.toml_data(settings))
        # both or neither: a PNG that fails to write leaves no scene file without its image
        write_together([(toml, lambda tmp: tmp.write_text(text, encoding="utf-8")),
                        (png, image_writer(png, f.image, f.exposure, self.tone))])
        return png, toml


def _medium_bytes(medium) -> int:
    """Bytes of a medium's grids (density, and per-voxel albedo or g)."""
    return sum(np.asarray(v).nbytes for v in (medium.density, medium.albedo, medium.g))


def encode_png(image: np.ndarray, exposure, tone: str = "aces") -> bytes:
    """PNG bytes of the tone-mapped float32 (H, W, 3) ``image`` (``exposure`` in stops or
    "auto", ``tone``; fast compression: the pixels are those ``popvol.write_image`` writes)."""
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(tonemap(image, exposure, tone), "RGB").save(buf, format="PNG", compress_level=1)
    return buf.getvalue()
