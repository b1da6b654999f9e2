"""popvol: interactive multiple scattering in participating media by Principal-Ordinate
Propagation (Elek, Ritschel, Dachsbacher, Seidel 2014).

The whole pipeline in a few names::

    import popvol
    scene = popvol.load_scene("examples/demo.toml")   # or load_scene() for the built-in demo
    solution = popvol.solve(scene)                     # propagate every light
    image = popvol.render(scene, solution)             # float32 (H, W, 3) linear HDR
    popvol.write_image("cloud.png", image, scene.method.exposure, scene.method.tone)

``write_image`` tone maps a PNG (exposure "auto" or stops; tone "aces", the ACES 2.0 SDR
view through OpenColorIO, or "clip") and writes an EXR linear. ``render_sequence(path,
"1-48", "out/frame_####.png")`` renders the frames of an animated scene (docs/SCENE.md,
"Sequences").
"""
import os as _os

if "NUMBA_THREADING_LAYER" not in _os.environ:
    # Numba's OpenMP layer unless the user chose one. Numba's default prefers TBB when a libtbb
    # is present (Debian's python3-openvdb pulls in libtbb12 2021.8); with it, a test process
    # that had run parallel kernels from several threads (viewer, Dask client) once spun in
    # tbb::finalize at exit for 20 minutes. OpenMP is thread-safe too; set
    # NUMBA_THREADING_LAYER=tbb to get TBB back.
    import numba as _numba
    try:
        from numba.np.ufunc import omppool as _omppool  # noqa: F401  (present and loadable)
        _numba.config.THREADING_LAYER = "omp"
    except ImportError:
        pass

from .errors import PopvolError
from .io.images import write_image
from .lights import DirectionalLight, PointLight
from .medium import Medium
from .method import Method
from .pipeline import solve
from .renderer import render
from .results import Solution
from .scene import Scene, load_scene, scene_from_dict
from .sequence import render_sequence

__all__ = ["PopvolError", "Scene", "Method", "Medium", "DirectionalLight", "PointLight", "load_scene",
           "scene_from_dict", "solve", "Solution", "render", "write_image", "render_sequence"]
__version__ = "0.1.0"
