"""popvol: interactive multiple scattering in participating media by Principal-Ordinate
Propagation (Elek, Ritschel, Dachsbacher, Seidel 2014).

The whole pipeline in three names::

    import popvol
    scene = popvol.load_scene("examples/demo.toml")   # or load_scene() for the built-in demo
    solution = popvol.solve(scene)                     # propagate every light
    image = popvol.render(scene, solution)             # float32 (H, W, 3) linear HDR
    popvol.write_image("cloud.png", image, scene.method.exposure)
"""
from .errors import PopvolError
from .scene import Scene, Method, load_scene, scene_from_dict
from .propagate import solve, propagate, Solution
from .render import render
from .io.images import write_image

__all__ = ["PopvolError", "Scene", "Method", "load_scene", "scene_from_dict", "solve", "propagate",
           "Solution", "render", "write_image"]
__version__ = "0.1.0"
