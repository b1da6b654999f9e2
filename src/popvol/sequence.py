"""Animated scenes: frame sequences of a medium, keyframed lights and camera, and rendering many
frames (docs/SCENE.md, "Sequences").

A scene becomes a sequence through any of:

- ``[medium] file = "smoke_####.npz"`` with ``frames = "1-24"``: one volume file per frame, a run
  of ``#`` standing for the zero-padded file number (Blender's convention: ``####`` -> 0001);
  ``mode`` says which file a frame outside ``frames`` reads (Blender's ``clip``, ``extend``,
  ``repeat``, ``pingpong``) and ``offset`` shifts file numbers against frame numbers;
- ``[sequence] frames = "1-48"``, ``fps = 24``: the frames rendered by default and the frame
  rate (a procedural cumulus or field gets ``time = medium.time + frame / fps``);
- ``[[keyframes]]``: ``frame = N`` with values of ``camera.origin``, ``camera.target``,
  ``camera.up``, ``camera.fov`` and each light's ``direction``, ``irradiance``, ``a0``
  (directional) or ``position``, ``intensity`` (point), interpolated linearly per field between
  the keyframes that set it and held before the first and after the last; interpolated
  directions are normalised again.

:func:`frame_data` turns the scene's data into the plain data of one frame (the loader,
:func:`popvol.scene.scene_from_dict`, then checks it as any scene); :class:`Sequence` holds a
parsed sequence and builds each frame's :class:`~popvol.scene.Scene`. :func:`render_run`
renders a run of frames in this process (what a Dask worker calls, see popvol.distributed) and
:func:`render_sequence` is the Python entry point. Frames are written atomically, and a small
record per frame (``.popvol/<image name>.json`` beside the image) lets a rerun skip the frames
already written for the same scene and method.
"""
from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import check
from .io.files import check_writable_folder, folder_problem
from .errors import PopvolError
from .procedural import MOVING_STYLES

__all__ = ["MODES", "MAX_FRAME", "parse_frames", "frames_text", "frame_path", "file_number", "Sequence",
           "load_sequence", "sequence_from_dict", "is_sequence", "frame_data", "frame_digest",
           "render_run", "render_sequence", "flicker", "write_video", "RECORD_DIR"]

#: Blender's sequence modes: what a frame outside ``medium.frames`` reads (clip: no medium;
#: extend: the first file before the range, the last after it; repeat: the files cycle;
#: pingpong: they cycle forth and back).
MODES = ("clip", "extend", "repeat", "pingpong")
#: Largest frame number (Blender's MAXFRAME).
MAX_FRAME = 1048574
#: Largest frames per second.
MAX_FPS = 1000.0
#: The folder (beside each frame's image) of the per-frame records of a rendered sequence.
RECORD_DIR = ".popvol"

_SEQUENCE_KEYS = {"frames", "fps"}
_MEDIUM_SEQUENCE_KEYS = ("frames", "mode", "offset")
_KEYFRAME_KEYS = {"frame", "camera", "lights"}
#: Keyframable camera fields: kind "point" (lerp), "direction" (lerp, normalised), "angle".
_CAMERA_FIELDS = {"origin": "point", "target": "point", "up": "direction", "fov": "angle"}
#: Keyframable fields of each light type: "direction", "point", "power" (1 or 3 numbers >= 0),
#: "unit" (a number in [0, 1]).
_LIGHT_FIELDS = {"directional": {"direction": "direction", "irradiance": "power", "a0": "unit"},
                 "point": {"position": "point", "intensity": "power"}}
_HASH_RUN = re.compile(r"#+")


# ---------------------------------------------------------------------------------------------
# Frame numbers
# ---------------------------------------------------------------------------------------------

def parse_frames(value, name: str, src: str) -> list[int]:
    """Frame numbers from ``value``: an integer, a list of integers, or a string of comma-separated
    items ``N``, ``A-B`` or ``A-B:STEP`` (every STEP-th frame from A to B, B included when it
    falls on the step), e.g. ``"1-240:2"`` or ``"1-10, 20"``. Every frame in [0, MAX_FRAME],
    strictly increasing (no repeats)."""
    allowed = (f"must be frame numbers in [0, {MAX_FRAME}]: an integer, a list of integers, or text "
               "like '1-240', '1-240:2' or '1-10, 20'")
    frames: list[int] = []
    if check._is_int(value):
        frames = [int(value)]
    elif isinstance(value, (list, tuple)) and value and all(check._is_int(v) for v in value) \
            and len(value) <= MAX_FRAME + 1:
        frames = [int(v) for v in value]
    elif isinstance(value, str) and value.strip() and len(value) <= 4096:
        for item in value.split(","):
            m = re.fullmatch(r"\s*([0-9]+)\s*(?:-\s*([0-9]+)\s*(?::\s*([0-9]+)\s*)?)?", item, re.ASCII)
            if not m:
                signed_step = re.fullmatch(r"\s*[0-9]+\s*-\s*[0-9]+\s*:\s*[-+]\s*[0-9]+\s*", item, re.ASCII)
                raise check._error(src, name, value, allowed + (" (A <= B, STEP >= 1)" if signed_step else ""))
            a = int(m.group(1))
            b = int(m.group(2)) if m.group(2) is not None else a
            step = int(m.group(3)) if m.group(3) is not None else 1
            if b > MAX_FRAME:
                raise check._error(src, name, value, allowed)
            if step < 1 or b < a:
                raise check._error(src, name, value, allowed + " (A <= B, STEP >= 1)")
            frames.extend(range(a, b + 1, step))
            if len(frames) > MAX_FRAME + 1:
                raise check._error(src, name, value, allowed)
    else:
        raise check._error(src, name, value, allowed)
    if not all(0 <= f <= MAX_FRAME for f in frames):
        raise check._error(src, name, value, allowed)
    for a, b in zip(frames, frames[1:]):
        if b <= a:
            raise check._error(src, name, value, f"must increase (frame {b} follows {a})")
    return frames


def frames_text(frames) -> str:
    """Frame numbers written compactly: ``[1, 2, 3, 5, 7, 9]`` -> ``"1-3, 5-9:2"`` (runs of at
    least three at one step), at most 12 items then ``...``."""
    frames = list(frames)
    items, i = [], 0
    while i < len(frames):
        j = i
        if i + 2 < len(frames):
            step = frames[i + 1] - frames[i]
            while j + 1 < len(frames) and frames[j + 1] - frames[j] == step:
                j += 1
            if j - i < 2:
                j = i
        if j > i:
            step = frames[i + 1] - frames[i]
            items.append(f"{frames[i]}-{frames[j]}" + (f":{step}" if step != 1 else ""))
        else:
            items.append(str(frames[i]))
        i = j + 1
    return ", ".join(items[:12]) + (", ..." if len(items) > 12 else "")


def has_pattern(path) -> bool:
    """Whether the file name (not its folder) of ``path`` holds a run of ``#``."""
    return bool(_HASH_RUN.search(Path(str(path)).name))


def frame_path(pattern, number: int, name: str = "file", src: str = "<sequence>") -> str:
    """``pattern`` with its run of ``#`` in the file name replaced by ``number``, zero-padded to
    the run's length (``smoke_####.npz``, 7 -> ``smoke_0007.npz``; longer numbers are not cut).
    The pattern must have exactly one run, in its file name."""
    pattern = str(pattern)
    p = Path(pattern)
    runs = _HASH_RUN.findall(p.name)
    if len(runs) != 1 or "#" in str(p.parent):
        raise PopvolError(f"{src}: {name} {pattern!r} must have one run of # (the frame number, e.g. "
                          f"frame_####.png) in its file name, got {len(runs)}"
                          + (" and # in its folder" if "#" in str(p.parent) else ""))
    m = _HASH_RUN.search(p.name)
    stem = p.name[:m.start()] + str(int(number)).zfill(len(runs[0])) + p.name[m.end():]
    return str(p.with_name(stem))


def file_number(frame: int, files: list[int], mode: str, offset: int = 0) -> int | None:
    """The number of the file a ``frame`` reads, from the numbers ``files`` that exist
    (increasing), Blender's sequence ``mode`` and ``offset`` (file number = frame + offset);
    None for a frame that ``clip`` hides.

    Inside [files[0], files[-1]] a number between two files reads the earlier one (files given
    every STEP frames are held for STEP frames). Outside: ``clip`` -> None; ``extend`` -> the
    first file before the range, the last after it; ``repeat`` -> cycles with period
    files[-1] - files[0] + (the last spacing, 1 for one file); ``pingpong`` -> forth and back,
    period 2 (files[-1] - files[0]) (Blender: 1 2 3 2 1 2 3 ...)."""
    n = frame + offset
    lo, hi = files[0], files[-1]
    if not lo <= n <= hi:
        if mode == "clip":
            return None
        if mode == "extend":
            n = lo if n < lo else hi
        elif mode == "repeat":
            period = hi - lo + (files[-1] - files[-2] if len(files) > 1 else 1)
            n = lo + (n - lo) % period
        elif mode == "pingpong":
            span = hi - lo
            if span == 0:
                n = lo
            else:
                x = (n - lo) % (2 * span)
                n = lo + (x if x <= span else 2 * span - x)
        else:
            raise PopvolError(f"sequence mode {mode!r} is unknown (known: {', '.join(MODES)})")
    i = int(np.searchsorted(np.asarray(files), n, side="right")) - 1
    return files[max(i, 0)]


# ---------------------------------------------------------------------------------------------
# A scene's sequence
# ---------------------------------------------------------------------------------------------

def is_sequence(data) -> bool:
    """Whether scene data (a dict) describes a sequence: a ``[sequence]`` table, ``[[keyframes]]``,
    or a medium file with a run of ``#`` or with ``frames``, ``mode`` or ``offset``."""
    if not isinstance(data, dict):
        return False
    if "sequence" in data or "keyframes" in data:
        return True
    m = data.get("medium")
    if not isinstance(m, dict):
        return False
    return (isinstance(m.get("file"), str) and has_pattern(m["file"])) or any(k in m for k in _MEDIUM_SEQUENCE_KEYS)


@dataclass
class Keyframe:
    frame: int
    values: dict        # ("camera", field) or (("lights", i), field) -> float64 array (or float)


@dataclass
class Sequence:
    """A scene's data with what varies over frames, parsed and checked.

    data: the scene's data as written (a dict); source: its name for messages; base_dir: the
    folder relative file names are resolved from; frames: the frames rendered by default
    (``sequence.frames``, else ``medium.frames``, else the keyframes' first to last; None for a
    still scene); fps: frames per second; pattern: ``medium.file`` when it holds a ``#`` run;
    files, mode, offset: ``medium.frames``, ``medium.mode``, ``medium.offset``; keyframes:
    sorted by frame.
    """

    data: dict
    source: str = "<dict>"
    base_dir: Path = Path(".")
    frames: list[int] | None = None
    fps: float = 24.0
    pattern: str | None = None
    files: list[int] | None = None
    mode: str = "clip"
    offset: int = 0
    keyframes: list[Keyframe] = field(default_factory=list)

    @property
    def animated(self) -> bool:
        return self.frames is not None

    def resolve_frames(self, frames=None, name: str = "frames", src: str | None = None) -> list[int]:
        """``frames`` (as :func:`parse_frames` takes them) or, if None, the scene's own frames;
        a still scene without ``frames`` is an error."""
        if frames is None:
            if self.frames is None:
                raise PopvolError(f"{self.source}: the scene has no frames ([sequence] frames, medium.frames "
                                  "or [[keyframes]]); give the frames to render (--frames 1-48)")
            return list(self.frames)
        return parse_frames(frames, name, src or self.source)

    def medium_file(self, frame: int) -> tuple[Path | None, bool]:
        """(the medium file ``frame`` reads, hidden): for a ``clip``ped frame the nearest file
        (its box keeps the camera and domains in place) and True. (None, False) without a
        pattern."""
        if self.pattern is None:
            return None, False
        n = file_number(frame, self.files, self.mode, self.offset)
        hidden = n is None
        if hidden:
            n = file_number(frame, self.files, "extend", self.offset)
        p = Path(frame_path(self.pattern, n, "medium.file", self.source))
        return (p if p.is_absolute() else self.base_dir / p), hidden

    def check_files(self, frames) -> None:
        """Refuse, naming them all, the medium files (and per-voxel grid files of the same
        sequence) that ``frames`` read and that do not exist; then refuse the first whose
        headers say it cannot be read (io.volumes.check_volume_header), naming its frame."""
        if self.pattern is None:
            return
        from .io.volumes import check_volume_header
        missing: dict[Path, int] = {}
        present: dict[Path, tuple[int, str | None]] = {}
        grid_missing = False
        m = self.data.get("medium", {})
        name = m.get("grid") if isinstance(m.get("grid"), str) else None
        grids = [(m[key]["file"], m[key].get("grid", key))      # per-voxel grids of the same sequence
                 for key in ("albedo", "g")
                 if isinstance(m.get(key), dict) and isinstance(m[key].get("file"), str) and has_pattern(m[key]["file"])]
        for f in frames:
            p, _ = self.medium_file(f)
            n = file_number(f, self.files, "extend", self.offset)
            for q, grid, array in [(p, False, name)] + [
                    (self.base_dir / frame_path(g, n, "medium grid file", self.source), True, a) for g, a in grids]:
                if q in missing or q in present:
                    continue
                if not q.is_file() or q.stat().st_size == 0:     # an empty file is none
                    missing[q] = n
                    grid_missing = grid_missing or grid
                else:
                    present[q] = (f, None if q.suffix.lower() == ".vol" else array)
        if missing:
            nums = sorted(set(missing.values()))
            names = ", ".join(p.name for p in list(missing)[:3]) + (", ..." if len(missing) > 3 else "")
            folder = next(iter(missing)).parent
            what = "medium.file and its grid files" if grid_missing else f"medium.file {self.pattern!r}"
            raise PopvolError(f"{self.source}: {what}: {len(nums)} file(s) of medium.frames "
                              f"missing or empty, numbers {frames_text(nums)} ({names} in {folder})")
        for q, (f, array) in present.items():
            try:
                check_volume_header(q, array if isinstance(array, str) else None)
            except PopvolError as e:
                raise PopvolError(f"{self.source}: frame {f}: {e}") from None

    def check_keyframes(self, frames, medium) -> None:
        """Refuse, naming its frame, the first of ``frames`` whose keyframed camera or lights are
        not a valid scene (e.g. an up vector that the interpolation makes parallel to the view),
        before any frame is rendered: each frame's camera and lights built as the loader builds
        them (popvol.scene.check_camera_and_lights), beside ``medium`` (the first frame's)."""
        if not self.keyframes:
            return
        from .scene import check_camera_and_lights
        for f in frames:
            try:
                check_camera_and_lights(self.frame_data(f)[0], medium, self.source, self.base_dir)
            except PopvolError as e:
                msg, head = str(e), f"{self.source}: "
                if f"frame {f}" not in msg:
                    msg = (head + f"frame {f}: " + msg[len(head):]) if msg.startswith(head) else f"frame {f}: {msg}"
                raise PopvolError(msg) from None

    def frame_data(self, frame: int) -> tuple[dict, bool]:
        """(the plain scene data of ``frame``, whether its medium is hidden by ``clip``)."""
        return _frame_data(self, int(frame))

    def scene(self, frame: int, **overrides):
        """The :class:`~popvol.scene.Scene` of ``frame``, with ``overrides`` as in
        :func:`popvol.scene.load_scene`."""
        from .scene import apply_overrides, scene_from_dict
        try:
            scene = scene_from_dict(self.data, self.source, self.base_dir, frame=frame)
        except PopvolError as e:        # name the frame: keyframes or a frame's file may be what is wrong
            msg, head = str(e), f"{self.source}: "
            if self.animated and f"frame {frame}" not in msg:
                msg = (head + f"frame {frame}: " + msg[len(head):]) if msg.startswith(head) else f"frame {frame}: {msg}"
            raise PopvolError(msg) from None
        return apply_overrides(scene, **overrides) if overrides else scene

    def time(self, frame: int) -> float:
        """The seconds of ``frame``: frame / fps."""
        return frame / self.fps


def load_sequence(path=None) -> Sequence:
    """The :class:`Sequence` of a scene file (``None``: the built-in demo, a still scene)."""
    if path is None:
        from .scene import DEMO_SCENE
        return sequence_from_dict(DEMO_SCENE, "<demo scene>")
    from .scene import read_scene_file
    p = Path(path)
    return sequence_from_dict(read_scene_file(p), str(p), p.parent)


def sequence_from_dict(data: dict, source: str = "<dict>", base_dir=".") -> Sequence:
    """Parse and check the sequence keys of scene data: ``[sequence]``, ``medium.frames``,
    ``medium.mode``, ``medium.offset``, the ``#`` run of ``medium.file`` and ``[[keyframes]]``
    (the rest of the scene is checked when a frame is built)."""
    src = source
    if not isinstance(data, dict):
        raise PopvolError(f"{src}: a scene must be a table/dict, got {type(data).__name__}")
    seq = Sequence(data, source, Path(base_dir))
    s = check.table(data.get("sequence", {}), "sequence", src)
    check.known_keys(s, _SEQUENCE_KEYS, "sequence.", src)
    seq.fps = check.number(s.get("fps", 24.0), "sequence.fps", src, 0.0, MAX_FPS, open_interval=True)
    m = data.get("medium")
    m = m if isinstance(m, dict) else {}
    given = [k for k in _MEDIUM_SEQUENCE_KEYS if k in m]
    file = m.get("file")
    if isinstance(file, str) and has_pattern(file):
        seq.pattern = check.text(file, "medium.file", src)
        frame_path(seq.pattern, 0, "medium.file", src)            # one run, in the file name
        if "frames" not in m:
            raise PopvolError(f"{src}: medium.file = {file!r} is a sequence (a run of # for the frame number); "
                              "give the numbers of its files as medium.frames, e.g. '1-240'")
        seq.files = parse_frames(m["frames"], "medium.frames", src)
        seq.mode = check.choice(m.get("mode", "clip"), "medium.mode", src, MODES)
        seq.offset = check.integer(m.get("offset", 0), "medium.offset", src, -MAX_FRAME, MAX_FRAME)
    elif given:
        where = ("medium.file has no run of # for the frame number (e.g. smoke_####.npz)"
                 if isinstance(file, str) else "the medium is not read from a file sequence")
        raise PopvolError(f"{src}: medium.{given[0]} applies to a medium file sequence, but {where}")
    seq.keyframes = _keyframes(data, src)
    if "frames" in s:
        seq.frames = parse_frames(s["frames"], "sequence.frames", src)
    elif seq.files is not None:
        seq.frames = [f - seq.offset for f in seq.files if f - seq.offset >= 0]
        if not seq.frames:
            raise PopvolError(f"{src}: medium.frames {frames_text(seq.files)} with medium.offset = {seq.offset} put "
                              "every file before frame 0 (frames are >= 0); lower medium.offset, or give "
                              "sequence.frames")
    elif seq.keyframes:
        seq.frames = list(range(seq.keyframes[0].frame, seq.keyframes[-1].frame + 1))
    return seq


def _keyframes(data: dict, src: str) -> list[Keyframe]:
    raw = data.get("keyframes", [])
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list):
        raise PopvolError(f"{src}: keyframes must be a list of [[keyframes]] tables")
    lights = data.get("lights", data.get("light", []))
    lights = [lights] if isinstance(lights, dict) else (lights if isinstance(lights, list) else [])
    out, seen = [], {}
    for i, k in enumerate(raw):
        name = f"keyframes[{i}]"
        check.table(k, name, src)
        check.known_keys(k, _KEYFRAME_KEYS, f"{name}.", src)
        if "frame" not in k:
            raise PopvolError(f"{src}: {name}.frame is required (the frame number the values hold at)")
        frame = check.integer(k["frame"], f"{name}.frame", src, 0, MAX_FRAME)
        if frame in seen:
            raise PopvolError(f"{src}: {name}.frame = {frame} is also keyframes[{seen[frame]}].frame; "
                              "each keyframe needs its own frame")
        seen[frame] = i
        values = {}
        cam = check.table(k.get("camera", {}), f"{name}.camera", src)
        check.known_keys(cam, _CAMERA_FIELDS, f"{name}.camera.", src)
        for key, kind in _CAMERA_FIELDS.items():
            if key in cam:
                values[("camera", key)] = _key_value(cam[key], kind, f"{name}.camera.{key}", src)
        kl = k.get("lights", {})
        if isinstance(kl, list):
            kl = {str(j): t for j, t in enumerate(kl)}
        check.table(kl, f"{name}.lights", src)
        for idx, t in kl.items():
            written = isinstance(idx, str) and idx.isascii() and idx.isdigit()     # 0-9 only, as frames
            j = int(idx) if check._is_int(idx) or written else None
            if j is None or not 0 <= j < len(lights):
                shown = idx if isinstance(idx, str) and idx.isprintable() and len(idx) <= 20 else check._show(idx)[:20]
                raise PopvolError(f"{src}: {name}.lights.{shown} names no light: the scene has "
                                  f"{len(lights)} [[lights]], numbered from 0 (write lights.0.direction = [...])")
            lname = f"{name}.lights.{j}"
            check.table(t, lname, src)
            base = lights[j] if isinstance(lights[j], dict) else {}
            kind = base.get("type", "directional")
            if kind not in _LIGHT_FIELDS:
                raise PopvolError(f"{src}: {lname}: lights[{j}] is a {kind!r} light; keyframes set fields of "
                                  "'directional' and 'point' lights only")
            check.known_keys(t, _LIGHT_FIELDS[kind], f"{lname}.", src)
            for key, vkind in _LIGHT_FIELDS[kind].items():
                if key in t:
                    values[(("lights", j), key)] = _key_value(t[key], vkind, f"{lname}.{key}", src)
        out.append(Keyframe(frame, values))
    return sorted(out, key=lambda kf: kf.frame)


def _key_value(value, kind: str, name: str, src: str):
    if kind == "point":
        return check.vector(value, name, src)
    if kind == "direction":
        v = check.vector(value, name, src, nonzero=True)
        v = v / np.abs(v).max()                # no overflow in the norm of [1e308, 1e308, 0]
        return v / np.linalg.norm(v)
    if kind == "power":
        return check.power(value, name, src)
    if kind == "unit":
        return check.number(value, name, src, 0.0, 1.0)
    return check.number(value, name, src, 0.0, 180.0, open_interval=True)       # angle (fov)


def _interpolate(keyframes: list[Keyframe], frame: int, src: str) -> dict:
    """Every keyed field's value at ``frame``: linear between the two keyframes around it that
    set the field, held before the first and after the last; directions normalised."""
    tracks: dict = {}
    for kf in keyframes:
        for key, v in kf.values.items():
            tracks.setdefault(key, []).append((kf.frame, v))
    out = {}
    for key, track in tracks.items():
        frames = [f for f, _ in track]
        i = int(np.searchsorted(frames, frame, side="right"))
        if i == 0:
            v = track[0][1]
        elif i == len(track):
            v = track[-1][1]
        else:
            (f0, v0), (f1, v1) = track[i - 1], track[i]
            t = (frame - f0) / (f1 - f0)
            v = (1 - t) * np.asarray(v0, np.float64) + t * np.asarray(v1, np.float64)
            if key[1] in ("direction", "up"):
                n = float(np.linalg.norm(v))
                if not n > 1e-9:
                    where = "camera" if key[0] == "camera" else f"lights.{key[0][1]}"
                    raise PopvolError(f"{src}: keyframes: {where}.{key[1]} turns through zero between frames "
                                      f"{f0} and {f1} (opposite directions); add a keyframe between them")
                v = v / n
        out[key] = v.tolist() if isinstance(v, np.ndarray) else v
    return out


def frame_data(data: dict, frame: int | None, source: str = "<dict>", base_dir=".") -> tuple[dict, bool, int]:
    """(the plain data of one frame of a scene, whether ``clip`` hides its medium, the frame):
    ``frame`` None is the scene's first frame (0 for a still scene)."""
    seq = sequence_from_dict(data, source, base_dir)
    if frame is None:
        frame = seq.frames[0] if seq.frames else 0
    frame = check.integer(frame, "frame", source, 0, MAX_FRAME)
    d, hidden = _frame_data(seq, frame)
    return d, hidden, frame


def _frame_data(seq: Sequence, frame: int) -> tuple[dict, bool]:
    data = {k: v for k, v in seq.data.items() if k not in ("sequence", "keyframes")}
    hidden = False
    m = data.get("medium")
    if isinstance(m, dict):
        m = {k: v for k, v in m.items() if k not in _MEDIUM_SEQUENCE_KEYS}
        if seq.pattern is not None:            # file names as written: the loader resolves them
            n = file_number(frame, seq.files, seq.mode, seq.offset)
            hidden = n is None
            if hidden:                          # clip: the nearest file's box, without its medium
                n = file_number(frame, seq.files, "extend", seq.offset)
            m["file"] = frame_path(seq.pattern, n, "medium.file", seq.source)
            for key in ("albedo", "g"):         # per-voxel grids of the same sequence
                t = m.get(key)
                if isinstance(t, dict) and isinstance(t.get("file"), str) and has_pattern(t["file"]):
                    m[key] = {**t, "file": frame_path(t["file"], n, f"medium.{key}.file", seq.source)}
        elif m.get("type", "file" if "file" in m else "procedural") == "procedural" \
                and m.get("style", "cumulus") in MOVING_STYLES:
            base = m.get("time", 0.0)
            if check._is_real(base) and math.isfinite(float(base)):     # else the loader names it
                from .procedural import TIME_LIMIT
                t = float(base) + seq.time(frame)
                if not abs(t) <= TIME_LIMIT:
                    raise PopvolError(f"{seq.source}: frame {frame}: medium.time + frame / sequence.fps = {t:g} s "
                                      f"must be within +-{TIME_LIMIT:g} (render earlier frames or raise sequence.fps)")
                m["time"] = t
        data["medium"] = m
    if seq.keyframes:
        values = _interpolate(seq.keyframes, frame, seq.source)
        cam = data.get("camera")
        cam = {} if cam is None else (dict(cam) if isinstance(cam, dict) else None)   # None: the loader refuses it
        lkey = "lights" if "lights" in data else "light"
        lights = data.get(lkey, [])
        lights = [dict(lights)] if isinstance(lights, dict) else \
            [dict(t) if isinstance(t, dict) else t for t in lights] if isinstance(lights, list) else []
        for (owner, key), v in values.items():
            if owner == "camera":
                if cam is not None:
                    cam[key] = v
            elif isinstance(lights[owner[1]], dict):
                lights[owner[1]][key] = v
        if cam is not None and any(o == "camera" for o, _ in values):
            data["camera"] = cam
        if lights and any(o != "camera" for o, _ in values):
            data[lkey] = lights
    return data, hidden


# ---------------------------------------------------------------------------------------------
# Rendering frames
# ---------------------------------------------------------------------------------------------

#: The keys of render_run's ``options``.
OPTION_KEYS = ("exr", "warm_start", "width", "height", "method")


def frame_digest(scene) -> str:
    """What a frame's images depend on: the scene as loaded (density, optics, lights, camera,
    background, environment: :func:`popvol.reference.scene_digest`) and every method field."""
    from .reference import scene_digest
    h = hashlib.sha256(scene_digest(scene).encode())
    h.update(json.dumps(vars(scene.method), sort_keys=True, default=str).encode())
    return h.hexdigest()[:20]


def record_path(image) -> Path:
    """The record of a frame's image: ``.popvol/<image name>.json`` in the image's folder."""
    image = Path(image)
    return image.parent / RECORD_DIR / (image.name + ".json")


def _read_record(image) -> dict | None:
    try:
        rec = json.loads(record_path(image).read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) else None


def _write_record(image, rec: dict) -> None:
    from .io.files import write_text_atomically
    p = record_path(image)
    try:
        p.parent.mkdir(exist_ok=True)
        write_text_atomically(p, json.dumps(_json_safe(rec), indent=1, allow_nan=False))
    except OSError as e:
        raise PopvolError(f"{p}: cannot write the frame's record ({e.strerror or e})") from None


def _done(image, exr, digest: str) -> dict | None:
    """The record of a frame already written for ``digest`` with every image asked for, else None."""
    rec = _read_record(image)
    if rec is None or rec.get("digest") != digest or not Path(image).is_file():
        return None
    if exr is not None and (rec.get("exr") != str(Path(exr).resolve()) or not Path(exr).is_file()):
        return None
    if rec.get("bytes") != _sizes(image, exr):
        return None
    exposure, seconds = rec.get("exposure"), rec.get("seconds")
    if not (exposure is None or (check._is_real(exposure) and math.isfinite(float(exposure)))) \
            or not isinstance(seconds, dict):
        return None                          # an edited record: the frame is rendered again
    return rec


def _json_safe(value):
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _solve(scene, warm):
    """popvol.solve, warm-started from the previous frame's solution where solve takes ``warm``."""
    from . import pipeline
    if warm is not None and "warm" in inspect.signature(pipeline.solve).parameters:
        return pipeline.solve(scene, warm=warm)
    return pipeline.solve(scene)


def _overrides(options: dict, src: str = "render_run") -> dict:
    if not isinstance(options, dict):
        raise PopvolError(f"{src}: options must be a dict, got {type(options).__name__}")
    check.known_keys(options, OPTION_KEYS, "options.", src)
    method = options.get("method") or {}
    if not isinstance(method, dict):
        raise PopvolError(f"{src}: options.method must be a dict of method knobs, got {check._show(method)}")
    ov = {k: v for k, v in method.items() if v is not None}
    for k in ("width", "height"):
        if options.get(k) is not None:
            ov[k] = options[k]
    return ov


def check_patterns(output, exr, frames, src: str = "render") -> None:
    """The output patterns (``output``: .png or .exr; ``exr``: .exr or None) fit ``frames``: a run
    of ``#`` in each file name for several frames (one frame may write a plain name), their
    folders exist, and they differ."""
    for opt, pat, suffixes in (("-o/--output", output, (".png", ".exr")), ("--exr", exr, (".exr",))):
        if pat is None:
            continue
        pat = str(pat)
        if Path(pat).suffix.lower() not in suffixes:
            raise PopvolError(f"{opt} {pat}: must end in {' or '.join(suffixes)}")
        if has_pattern(pat):                # (a # in the folder of a plain name is just a character)
            frame_path(pat, 0, opt, src)
        elif len(frames) > 1:
            raise PopvolError(f"{opt} {pat}: {len(frames)} frames ({frames_text(frames)}) need a run of # in the "
                              "file name for the frame number (e.g. out/frame_####.png), or render one frame "
                              "(--frames N)")
        folder = Path(pat).resolve().parent
        if problem := folder_problem(folder):
            raise PopvolError(f"{opt} {pat}: folder {folder} {problem}")
        check_writable_folder(folder, f"{opt} {pat}")
    if exr is not None and Path(str(exr)).resolve() == Path(str(output)).resolve():
        raise PopvolError(f"--exr {exr} is also -o/--output; give them different names")


def check_frame_outputs(seq: Sequence, scene_path, output, exr, frames) -> None:
    """Before any frame is rendered: no frame's image (``output``) or EXR (``exr``) is one of
    the files the scene reads in any of ``frames`` (the scene file, each frame's medium file,
    maps and grids), and no two frames write the same file (e.g. c_1#.exr of frame 0 and c_#.exr
    of frame 10)."""
    from .scene import _files
    inputs = {Path(scene_path).resolve(): "the scene file"} if scene_path else {}
    # a frame's files differ from the first frame's only through medium.file's run of #
    for f in frames if seq.pattern is not None else frames[:1]:
        for p in _files(seq.frame_data(f)[0], Path(seq.base_dir)):
            inputs.setdefault(p, f"an input file of frame {f}")
    inputs = {str(p): what for p, what in inputs.items()}
    written: dict[str, str] = {}
    # by strings, the folder resolved once: a million frames are checked in seconds
    outputs = []
    for opt, pat in (("-o/--output", output), ("--exr", exr)):
        if pat is not None:
            path = Path(str(pat))
            m = _HASH_RUN.search(path.name) if has_pattern(pat) else None
            head, width, tail = (path.name[:m.start()], m.end() - m.start(), path.name[m.end():]) if m else \
                (path.name, 0, "")
            outputs.append((opt, str(path.parent.resolve()) + os.sep, head, width, tail, m is not None))
    for f in frames:
        for opt, folder, head, width, tail, numbered in outputs:
            p = folder + (head + str(int(f)).zfill(width) + tail if numbered else head)
            if os.path.islink(p):           # an output that links to an input overwrites it
                p = str(Path(p).resolve())
            if p in inputs or p in written:
                shown = frame_path(output if opt == "-o/--output" else exr, f) if numbered else \
                    (output if opt == "-o/--output" else exr)
                if p in inputs:
                    raise PopvolError(f"{opt} {shown} (frame {f}) is {inputs[p]}; writing it would overwrite it")
                raise PopvolError(f"{opt} {shown} (frame {f}) is also {written[p]}; give every frame its own "
                                  "file (a run of # for the whole frame number)")
            written[p] = f"{opt} of frame {f}"


def _frame_paths(output, exr, frame: int) -> tuple[Path, Path | None]:
    image = Path(frame_path(output, frame) if has_pattern(output) else output)
    return image, (None if exr is None else Path(frame_path(exr, frame) if has_pattern(exr) else exr))


def render_run(scene_path, frames, output: str, options: dict | None = None, progress=None) -> list[dict]:
    """Render ``frames`` (increasing frame numbers, usually a contiguous run) of the scene file
    ``scene_path`` (None: the built-in demo) in order, in this process, and write each frame
    atomically to ``output`` (a .png or .exr name whose run of ``#`` is the frame number;
    ``options["exr"]``: also a linear EXR per frame). A frame whose record (``.popvol/<image
    name>.json`` beside its image) has the same :func:`frame_digest` and whose images exist is
    skipped. Records are one file per frame, each written atomically, so processes rendering
    other frames into the same folder do not meet.

    ``options`` (plain data, picklable): ``exr`` (pattern or None), ``warm_start`` (default
    True: each frame's solve starts from the previous frame's solution, where popvol.solve
    takes ``warm``), ``width``, ``height`` (pixels), ``method`` (a dict of method knobs, any of
    popvol.method.KNOBS, e.g. ``{"resolution": 64, "exposure": 1.5}``). An ``exposure`` of
    "auto" meters each PNG by itself; :func:`render_sequence` fixes one for all frames.
    ``progress``: optional callable(result) after each frame.

    Returns one dict per frame: frame, path (its image), exr (or None), skipped, seconds (load,
    resample, propagate, diffusion, fields, render, write, total; a skipped frame: load and
    total), iterations and diffusion_iterations (one per light domain), exposure (the PNG's
    stops, or None), digest, hidden (a medium ``clip``ped away), warnings.
    """
    options = dict(options or {})
    overrides = _overrides(options)
    exr = options.get("exr")
    warm_start = bool(options.get("warm_start", True))
    seq = load_sequence(scene_path)
    frames = [int(f) for f in frames]
    frames = parse_frames(frames, "frames", seq.source) if frames else []
    check_patterns(output, exr, frames)
    check_frame_outputs(seq, scene_path, output, exr, frames)
    seq.check_files(frames)
    results, prev = [], None
    for frame in frames:
        t0 = time.perf_counter()
        sc = seq.scene(frame, **overrides)
        image, exr_path = _frame_paths(output, exr, frame)
        digest = frame_digest(sc)
        rec = _done(image, exr_path, digest)
        if rec is not None:
            t = time.perf_counter() - t0
            res = {"frame": frame, "path": str(image), "exr": None if exr_path is None else str(exr_path),
                   "skipped": True, "seconds": {"load": t, "total": t},
                   "iterations": rec.get("iterations", []), "diffusion_iterations": rec.get("diffusion_iterations", []),
                   "exposure": rec.get("exposure"), "digest": digest, "hidden": rec.get("hidden", False),
                   "warnings": []}
            results.append(res)
            prev = None
            if progress:
                progress(res)
            continue
        img, solution, seconds = _solve_render(sc, prev if warm_start else None, t0)
        res = _write_frame(sc, frame, image, exr_path, img, solution, seconds, t0)
        prev = solution if warm_start else None
        results.append(res)
        if progress:
            progress(res)
    return results


def _solve_render(sc, warm, t0):
    """Solve (warm-started from ``warm``) and render one frame's scene: (image, solution,
    seconds so far: load, resample, propagate, diffusion, fields, render)."""
    from .renderer import render as render_image
    t_load = time.perf_counter() - t0
    solution = _solve(sc, warm)
    t1 = time.perf_counter()
    img = render_image(sc, solution)
    return img, solution, {"load": t_load, **solution.seconds, "render": time.perf_counter() - t1}


def _write_frame(sc, frame, image, exr_path, img, solution, seconds, t0) -> dict:
    """Write one rendered frame's images (the PNG with the method's exposure, "auto" metering
    this frame) and its record; the frame's result dict."""
    from .io.images import resolve_exposure, write_image
    t2 = time.perf_counter()
    exposure = None
    if image.suffix.lower() == ".png":
        exposure = float(min(64.0, max(-64.0, resolve_exposure(img, sc.method.exposure, sc.method.tone))))
        write_image(image, img, exposure, sc.method.tone, exr=exr_path)
    else:
        write_image(image, img, exr=exr_path)
    info = solution.stats()
    warnings = []
    for d in info["domains"]:
        if not d.get("converged", True):
            warnings.append(f"frame {frame}: light {d['light']} stopped after {d['iterations']} iterations with "
                            f"{d['residual']:.1e} of its energy in flight; raise method.max_iterations")
    capped = solution.medium.capped_scattering_warning()     # the grid it was solved on
    if capped:
        warnings.append(f"frame {frame}: {capped}")
    res = {"frame": frame, "path": str(image), "exr": None if exr_path is None else str(exr_path),
           "skipped": False,
           "seconds": {**seconds, "write": time.perf_counter() - t2, "total": time.perf_counter() - t0},
           "iterations": [d["iterations"] for d in info["domains"]],
           "diffusion_iterations": [d.get("diffusion_iterations", 0) for d in info["domains"]],
           "exposure": exposure, "digest": frame_digest(sc), "hidden": bool(sc.hidden), "warnings": warnings}
    _write_record(image, {**res, "exr": None if exr_path is None else str(exr_path.resolve()),
                          "scene": sc.source, "method": vars(sc.method), "bytes": _sizes(image, exr_path)})
    return res


def _sizes(image, exr) -> list:
    """The sizes in bytes of a frame's image and EXR (None where absent): a rerun re-renders a
    frame whose files are not those its record wrote (truncated, emptied, replaced)."""
    return [Path(p).stat().st_size if p is not None and Path(p).is_file() else None for p in (image, exr)]


def _meter(seq: Sequence, frames, output, exr, overrides) -> tuple[float, int, dict | None]:
    """One exposure for every frame of a sequence whose method.exposure is "auto": the auto
    exposure of its middle frame (of those whose medium ``clip`` does not hide); (stops, that
    frame, its result if it was rendered here). The middle frame is rendered here and written with those stops (so the run that follows skips
    it), and the stops are kept in a record beside the frames (``.popvol/<output
    pattern>.exposure.json``) for reruns."""
    from .io.files import write_text_atomically
    from .io.images import auto_exposure
    # the middle of the frames that show the medium (clip can hide it): a hidden frame's exposure
    # would be the background's
    shown = [f for f in frames if not seq.medium_file(f)[1]] or list(frames)
    mid = shown[len(shown) // 2]
    sc = seq.scene(mid, **overrides)
    key = frame_digest(sc)
    meter = Path(str(output)).parent / RECORD_DIR / (Path(str(output)).name + ".exposure.json")
    try:
        rec = json.loads(meter.read_text())
        stops = rec.get("exposure")
        if rec.get("digest") == key and check._is_real(stops) and -64.0 <= float(stops) <= 64.0:
            return float(stops), mid, None       # else (an edited record) metered again
    except (OSError, ValueError, AttributeError):
        pass
    t0 = time.perf_counter()
    img, solution, seconds = _solve_render(sc, None, t0)
    stops = float(min(64.0, max(-64.0, auto_exposure(img, tone=sc.method.tone))))
    sc.method.exposure = stops
    image, exr_path = _frame_paths(output, exr, mid)
    res = _write_frame(sc, mid, image, exr_path, img, solution, seconds, t0)
    try:
        meter.parent.mkdir(exist_ok=True)
        write_text_atomically(meter, json.dumps({"digest": key, "exposure": stops, "frame": mid}))
    except OSError as e:
        raise PopvolError(f"{meter}: cannot write ({e.strerror or e})") from None
    return stops, mid, res


def render_sequence(scene, frames=None, output: str = "frame_####.png", *, client=None, warm_start: bool = True,
                    exr: str | None = None, progress=None, **overrides) -> list[dict]:
    """Render frames of the scene file ``scene`` (a path; None: the built-in demo) to images
    named by ``output`` (.png or .exr; its run of ``#`` is the frame number) and, with ``exr``,
    linear EXRs too; returns :func:`render_run`'s dicts, one per frame, in frame order.

    ``frames``: frame numbers (a list, or text like "1-48" / "1-240:2"); None: the scene's own.
    With a PNG output and ``method.exposure = "auto"``, every frame gets ONE exposure, the
    auto exposure of the middle frame (so the sequence does not pump), measured first.
    ``client``: a dask.distributed Client; the frames are then rendered on its workers by
    :func:`popvol.distributed.run_on_cluster`. ``warm_start``: each frame's solve starts from
    the previous frame's solution. ``progress``: callable(result) after each frame.
    ``overrides``: width, height and method knobs, as for :func:`popvol.load_scene`.
    """
    from .io.files import file_name
    from .method import KNOB
    scene_path = None if scene is None else str(file_name(scene, "render_sequence: scene (the scene file's path)"))
    file_name(output, "render_sequence: output")
    if exr is not None:
        file_name(exr, "render_sequence: exr")
    if progress is not None and not callable(progress):
        raise PopvolError(f"render_sequence: progress must be a function (result) or None, not "
                          f"{type(progress).__name__}")
    if client is not None and not hasattr(client, "submit"):
        raise PopvolError(f"render_sequence: client must be a dask.distributed Client or None, not "
                          f"{type(client).__name__}")
    unknown = sorted(k for k in overrides if k not in KNOB and k not in ("width", "height"))
    if unknown:
        raise PopvolError(f"render_sequence: unknown option(s) {', '.join(unknown)} (known: width, height and the "
                          "method's knobs; frames are chosen by frames)")
    seq = load_sequence(scene_path)
    frames = seq.resolve_frames(frames)
    check_patterns(output, exr, frames)
    check_frame_outputs(seq, scene_path, output, exr, frames)
    seq.check_files(frames)
    width, height = overrides.pop("width", None), overrides.pop("height", None)
    options = {"exr": None if exr is None else str(exr), "warm_start": bool(warm_start),
               "width": width, "height": height, "method": {k: v for k, v in overrides.items() if v is not None}}
    ov = _overrides(options, "render_sequence")
    probe = seq.scene(frames[0], **ov)                 # checks the overrides and the first frame
    seq.check_keyframes(frames, probe.medium)          # and every frame's camera and lights
    mid, first = None, None
    if Path(str(output)).suffix.lower() == ".png" and probe.method.exposure == "auto":
        stops, mid, first = _meter(seq, frames, str(output), options["exr"], ov)
        options["method"]["exposure"] = stops

    def merged(r: dict) -> dict:
        """The run's result, but the metering render's for the middle frame (the run skipped it)."""
        if first is not None and r["frame"] == mid and r["skipped"] and r["digest"] == first["digest"]:
            r = first
        return {**r, "metered_frame": mid} if mid is not None else r

    if client is not None:
        from .distributed import run_on_cluster
        kw = {"progress": False} if progress and "progress" in inspect.signature(run_on_cluster).parameters else {}
        results = run_on_cluster(client, scene_path, frames, str(output), options, **kw)
        results = [merged(r) for r in sorted(results, key=lambda r: r["frame"])]
        if progress:
            for r in results:
                progress(r)
    else:
        results = render_run(scene_path, frames, str(output), options,
                             progress=(lambda r: progress(merged(r))) if progress else None)
        results = [merged(r) for r in results]
    return results


# ---------------------------------------------------------------------------------------------
# Temporal stability and video
# ---------------------------------------------------------------------------------------------

def _display_image(result: dict, exposure, tone: str) -> np.ndarray:
    """uint8 (H, W, 3): a frame's PNG, or its EXR tone mapped with ``exposure``."""
    path = Path(result["path"])
    if path.suffix.lower() == ".png":
        from PIL import Image
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    from .io.images import read_exr, tonemap
    return tonemap(read_exr(path), exposure, tone)


def _relative_change(a: np.ndarray, b: np.ndarray) -> float:
    """mean |a - b| / mean (a + b) / 2 (0 when both are 0)."""
    den = 0.5 * (float(np.mean(a, dtype=np.float64)) + float(np.mean(b, dtype=np.float64)))
    num = float(np.mean(np.abs(a.astype(np.float64) - b), dtype=np.float64))
    return num / den if den > 0 else 0.0


def _density_on(medium, lo, hi, n: int = 48) -> np.ndarray:
    """The medium's density sampled (nearest voxel, 0 outside) on n^3 points of the box [lo, hi]."""
    axes = [lo[a] + (np.arange(n) + 0.5) * (hi[a] - lo[a]) / n for a in range(3)]
    idx, ok = [], np.ones((n, n, n), bool)
    for a in range(3):
        i = np.floor((axes[a] - medium.origin[a]) / medium.voxel_size[a] + 0.5).astype(np.int64)
        shape = [1, 1, 1]
        shape[a] = n
        inside = (i >= 0) & (i < medium.density.shape[a])
        idx.append(np.clip(i, 0, medium.density.shape[a] - 1).reshape(shape))
        ok &= inside.reshape(shape)
    return np.where(ok, medium.density[idx[0], idx[1], idx[2]], 0.0)


def _density_change(m0, m1, hidden0: bool, hidden1: bool) -> float:
    d0 = np.zeros_like(m0.density) if hidden0 else m0.density
    d1 = np.zeros_like(m1.density) if hidden1 else m1.density
    if m0.density.shape == m1.density.shape and np.array_equal(m0.origin, m1.origin) \
            and np.array_equal(m0.voxel_size, m1.voxel_size):
        return _relative_change(d0, d1)
    (lo0, hi0), (lo1, hi1) = m0.bounds, m1.bounds
    lo, hi = np.minimum(lo0, lo1), np.maximum(hi0, hi1)
    a = _density_on(m0, lo, hi) * (not hidden0)
    b = _density_on(m1, lo, hi) * (not hidden1)
    return _relative_change(a, b)


def flicker(scene, results: list[dict], exposure=None, **overrides) -> dict:
    """The temporal stability of rendered frames (``results`` of :func:`render_sequence`, in
    frame order) of the scene file ``scene``.

    For each pair of consecutive frames: the image change, mean |Y1 - Y0| / mean (Y0 + Y1) / 2
    with Y the display luminance (the 8-bit PNG, or the EXR tone mapped with ``exposure``,
    sRGB-decoded, Rec.709 weights), and the density change, the same on the media's density
    grids (on a common 48^3 grid where their boxes differ; a ``clip``ped medium is 0). The
    flicker figure is mean image change / mean density change: how much the picture moves per
    unit of change in the medium (None when the medium never changes). Pairs with the same
    :func:`frame_digest` (a static pair: same scene and method) must be identical images; their
    largest image change is reported as ``static_max_image_change``. With a keyframed camera or
    lights the image also moves where the medium does not, and the figure says so only
    together with ``image`` alone.
    """
    from .io.images import LUMINANCE
    seq = load_sequence(None if scene is None else str(scene))
    results = sorted(results, key=lambda r: r["frame"])
    if exposure is None and results and Path(results[0]["path"]).suffix.lower() != ".png":
        m = seq.scene(results[0]["frame"], **overrides).method      # EXR frames: one exposure for all
        if m.exposure == "auto":
            from .io.images import auto_exposure, read_exr
            exposure = auto_exposure(read_exr(results[len(results) // 2]["path"]), tone=m.tone)
        else:
            exposure = m.exposure
    pairs, static = [], []
    prev_img = prev_med = prev = None
    tone = None
    for r in results:
        sc = seq.scene(r["frame"], **overrides)
        tone = sc.method.tone
        img = _display_image(r, exposure, tone).astype(np.float64) / 255.0
        lin = np.where(img <= 0.04045, img / 12.92, ((img + 0.055) / 1.055) ** 2.4)
        y = sum(w * lin[..., i] for i, w in enumerate(LUMINANCE))
        hidden = sc.hidden
        if prev is not None:
            di = _relative_change(prev_img, y) if prev_img.shape == y.shape else None
            dd = _density_change(prev_med, sc.medium, prev["hidden"], hidden)
            pairs.append({"frames": [prev["frame"], r["frame"]], "image": di, "density": dd})
            if prev["digest"] == r.get("digest") and di is not None:
                static.append(di)
        prev_img, prev_med, prev = y, sc.medium, {"frame": r["frame"], "hidden": hidden, "digest": r.get("digest")}
    imgs = [p["image"] for p in pairs if p["image"] is not None]
    dens = [p["density"] for p in pairs]
    mi = float(np.mean(imgs)) if imgs else None
    md = float(np.mean(dens)) if dens else None
    return {"definition": "mean over consecutive frame pairs of mean|Y1 - Y0| / mean((Y0 + Y1) / 2), Y the "
                          "display luminance (image) or the density (medium); flicker = image / density",
            "image": mi, "density": md, "flicker": (mi / md) if (mi is not None and md) else None,
            "static_pairs": len(static), "static_max_image_change": max(static) if static else None,
            "pairs": pairs}


def video_fps(fps: float, frames) -> float:
    """The video's frame rate: ``fps`` divided by the frames' usual spacing (every 2nd frame of a
    24 fps sequence plays at 12 fps, at the scene's speed)."""
    steps = np.diff(np.asarray(list(frames)))
    return fps / float(np.median(steps)) if steps.size else fps


def write_video(path, results: list[dict], fps: float, exposure="auto", tone: str = "aces") -> float | None:
    """Write the frames of ``results`` (in frame order) as an H.264 MP4 at ``fps``, atomically.
    PNG frames are used as written (their exposure is already the sequence's); EXR frames are
    tone mapped with ``exposure``, one for all frames ("auto": the middle frame's auto exposure).
    Odd sizes are padded by one edge pixel (yuv420p needs even sides). Returns the stops used
    for EXR frames (None for PNG frames). Needs imageio-ffmpeg (pip install 'popvol[video]')."""
    imageio_ffmpeg = import_video_writer()
    from .io.files import write_atomically
    from .io.images import auto_exposure, read_exr
    results = sorted(results, key=lambda r: r["frame"])
    if not results:
        raise PopvolError(f"--video {path}: no frames to assemble")
    stops = None
    if Path(results[0]["path"]).suffix.lower() != ".png":
        stops = exposure
        if exposure == "auto":
            stops = auto_exposure(read_exr(results[len(results) // 2]["path"]), tone=tone)
    first = _display_image(results[0], stops, tone)
    h, w = first.shape[:2]
    H, W = h + h % 2, w + w % 2

    def write(tmp):
        gen = imageio_ffmpeg.write_frames(str(tmp), (W, H), fps=float(fps), codec="libx264", pix_fmt_out="yuv420p",
                                          macro_block_size=1, quality=8, ffmpeg_log_level="error")
        gen.send(None)
        for r in results:
            im = first if r is results[0] else _display_image(r, stops, tone)
            if im.shape[:2] != (h, w):
                raise PopvolError(f"{r['path']}: frame is {im.shape[1]}x{im.shape[0]}, the first {w}x{h}; "
                                  "a video needs frames of one size")
            gen.send(np.ascontiguousarray(np.pad(im, ((0, H - h), (0, W - w), (0, 0)), mode="edge")))
        gen.close()

    try:
        write_atomically(path, write)
    except OSError as e:
        raise PopvolError(f"--video {path}: cannot write ({e.strerror or e})") from None
    except RuntimeError as e:
        raise PopvolError(f"--video {path}: ffmpeg failed ({' '.join(str(e).split())[:300]})") from None
    return stops


def import_video_writer():
    """The imageio_ffmpeg module, or a one-line error saying how to install it."""
    try:
        import imageio_ffmpeg
        imageio_ffmpeg.get_ffmpeg_exe()
    except ImportError:
        raise PopvolError("--video needs imageio-ffmpeg (it brings its own ffmpeg): "
                          "pip install 'popvol[video]'") from None
    except RuntimeError as e:
        raise PopvolError(f"--video: imageio-ffmpeg finds no ffmpeg ({e})") from None
    return imageio_ffmpeg
