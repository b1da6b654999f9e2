"""Command line: ``popvol render``, ``view``, ``reference``, ``compare``, ``bench``, ``hg-figure``.

The method options of ``render`` and ``compare`` (``--resolution``, ``--spp``, ...) are made
from the knobs of :mod:`popvol.method` that name the command; experimental knobs are not
offered here (a scene's ``[experimental]`` table sets them). Bad input ends with one line
``popvol: error: ...`` on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from pathlib import Path

import click

from .errors import PopvolError
from .method import KNOBS, cli_knobs


def method_options(command: str):
    """Decorator: a ``--name`` option for each knob of :func:`popvol.method.cli_knobs`
    (``command``), passed to the command as a keyword argument named like the knob (None when
    not given)."""
    def decorate(f):
        for k in reversed(cli_knobs(command)):
            f = click.option(k.option, k.name, type=k.cli_type, default=None, help=k.help)(f)
        return f
    return decorate


def _method_overrides(command: str, knobs: dict) -> dict:
    """The method options given on the command line, each checked (a bad one is named as the
    option)."""
    given = {}
    for k in cli_knobs(command):
        if knobs.get(k.name) is not None:
            given[k.name] = k.check(k.cli_value(knobs[k.name]), f"popvol {command}", k.option)
    return given


def _progress():
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                    TimeElapsedColumn(), transient=True, disable=not sys.stderr.isatty())


#: said once on a terminal when Numba compiles a kernel of popvol's instead of loading it
COMPILING = ("popvol: compiling the Numba kernels for this machine (the first run only: about a minute "
             "on 2 cores; later runs load them from Numba's cache)")


def announce_compiling(say) -> object:
    """Call ``say(COMPILING)`` once, when Numba first compiles one of popvol's kernels in this
    process; loading a kernel from Numba's cache is no compile and says nothing. Without it the
    first run's minute of compiling shows as a progress bar that stands still. Returns the
    listener (``numba.core.event.unregister("numba:compile", listener)`` removes it)."""
    from numba.core import event

    class FirstCompile(event.Listener):
        said = False

        def on_start(self, ev):
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            if not self.said and getattr(func, "__module__", "").startswith("popvol."):
                self.said = True
                say(COMPILING)

        def on_end(self, ev):
            pass

    listener = FirstCompile()
    event.register("numba:compile", listener)
    return listener


@click.group()
@click.version_option(package_name="popvol")
def cli():
    """popvol: multiple scattering in clouds and smoke by Principal-Ordinate Propagation."""
    if sys.stderr.isatty():              # as the progress bars: on a terminal only
        announce_compiling(lambda line: click.echo(line, err=True))


@cli.command()
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", default="cloud.png", show_default=True, help="Image to write (.png or .exr).")
@click.option("--exr", type=click.Path(dir_okay=False), help="Also write the linear HDR image as EXR.")
@click.option("--width", type=int, help="Image width in pixels (overrides the scene).")
@click.option("--height", type=int, help="Image height in pixels (overrides the scene).")
@method_options("render")
@click.option("--stats", type=click.Path(dir_okay=False), help="Write timings, iterations and energy budget as JSON.")
@click.option("--frames", help="Frames to render, e.g. 1-240, 1-240:2 or 1-10,20 (overrides the scene's); "
                               "-o then needs a run of # for the frame number.")
@click.option("--video", type=click.Path(dir_okay=False),
              help="With frames: also assemble them into an MP4 (needs pip install 'popvol[video]').")
@click.option("--workers", type=int, help="With frames: render on a local Dask cluster of N worker processes.")
@click.option("--scheduler", help="With frames: render on the Dask cluster at this address (tcp://HOST:PORT).")
@click.option("--no-warm-start", is_flag=True, help="With frames: solve every frame from scratch.")
def render(scene, output, exr, width, height, stats, frames, video, workers, scheduler, no_warm_start, **knobs):
    """Render SCENE (a TOML file; the built-in demo cloud if omitted) to an image, or the
    frames of an animated scene (docs/SCENE.md, "Sequences") to one image per frame. An image
    of a single scene that shows no medium, or is black, is written with a warning."""
    from .io.files import write_text_atomically
    from .io.images import write_image
    from . import solve
    from .renderer import render as render_image
    from .scene import load_scene
    from .sequence import load_sequence

    seq = load_sequence(scene) if (scene or frames) else None
    if frames is not None or (seq is not None and seq.animated):
        return _render_frames(seq, scene, output, exr, width, height, stats, frames, video, workers, scheduler,
                              not no_warm_start, _method_overrides("render", knobs))
    for option, value in (("--video", video), ("--workers", workers), ("--scheduler", scheduler),
                          ("--no-warm-start", no_warm_start or None)):
        if value is not None:
            raise PopvolError(f"{option} applies to frames of a sequence; the scene has none (give --frames)")

    outputs = {"-o/--output": (output, (".png", ".exr")), "--exr": (exr, (".exr",)), "--stats": (stats, (".json",))}
    _check_outputs(outputs, [scene] if scene else [])
    t0 = time.perf_counter()
    sc = load_scene(scene, width=width, height=height, **_method_overrides("render", knobs))
    _check_outputs(outputs, sc.files)
    from .domains import check_image_memory
    check_image_memory(sc.camera.width, sc.camera.height, f"{sc.source}: camera.width x camera.height")
    t_load = time.perf_counter() - t0
    tol = sc.method.tolerance
    with _progress() as bar:
        tasks = {}
        new_task = threading.Lock()     # domains may be solved side by side (pipeline.side_by_side)

        def on_progress(light, it, residual):
            with new_task:
                if light not in tasks:
                    tasks[light] = bar.add_task(f"light {light}: propagating", total=1.0, info="")
            frac = min(1.0, max(0.0, math.log(max(residual, 1e-300)) / math.log(tol)))
            bar.update(tasks[light], completed=frac, info=f"iteration {it}, in flight {residual:.1e}")

        solution = solve(sc, progress=on_progress)
        task = bar.add_task("rendering", total=None, info=f"{sc.camera.width}x{sc.camera.height}")
        t1 = time.perf_counter()
        img = render_image(sc, solution)
        t_render = time.perf_counter() - t1
        bar.update(task, completed=1, total=1)
    t2 = time.perf_counter()
    write_image(output, img, sc.method.exposure, sc.method.tone, exr=exr or None)
    t_write = time.perf_counter() - t2
    seconds = {"load": t_load, **solution.seconds, "render": t_render, "write": t_write,
               "total": time.perf_counter() - t0}
    info = solution.stats()
    from .metrics import MASK_OPTICAL_DEPTH, medium_in_view
    black = not img.any()
    if not medium_in_view(sc):          # a legitimate render, but rarely the one meant
        click.echo(f"popvol: warning: no camera ray crosses the medium (optical depth > {MASK_OPTICAL_DEPTH:g} "
                   "through a pixel's centre): the camera looks away from it, or medium.scale x its density is too "
                   f"thin to see; {output} shows the background alone" + (", which is black" if black else ""),
                   err=True)
    elif black:
        click.echo("popvol: warning: the image is black (every pixel 0): no light reaches the camera from the "
                   f"medium; {_why_black(sc, info)}", err=True)
    elif Path(output).suffix.lower() == ".png" and sc.method.exposure != "auto":
        from .io.images import auto_exposure, tonemap
        if not tonemap(img, sc.method.exposure, sc.method.tone).any():
            click.echo(f"popvol: warning: {output} is black at exposure {sc.method.exposure:g} stops, though the "
                       f"image is not (exposure 'auto' gives {auto_exposure(img, tone=sc.method.tone):+.1f})"
                       + (f"; {exr} holds the linear values" if exr else ""), err=True)
    for d in info["domains"]:
        if not d["converged"]:
            click.echo(f"popvol: warning: light {d['light']} stopped after {d['iterations']} iterations "
                       f"with {d['residual']:.1e} of its energy still in flight (tolerance {tol:g}); "
                       "raise method.max_iterations for a converged image", err=True)
    capped = solution.medium.capped_scattering_warning()     # the grid it was solved on
    if capped:
        click.echo(f"popvol: warning: {capped}", err=True)
    if stats:
        doc = {"scene": sc.source, "image": str(output), "width": sc.camera.width, "height": sc.camera.height,
               "method": vars(sc.method), "seconds": seconds, "grid": info["grid"], "domains": info["domains"]}
        try:
            write_text_atomically(stats, json.dumps(_json_safe(doc), indent=2, allow_nan=False))
        except OSError as e:
            raise PopvolError(f"--stats {stats}: cannot write ({e.strerror or e})") from None
    its = ", ".join(str(d["iterations"]) for d in info["domains"])
    solvers = "/".join(sorted({d["solver"] for d in info["domains"]}))
    walked = f"{solvers}, {its} iterations" if info["domains"] else "no light with power to propagate"
    click.echo(f"{output}: {sc.camera.width}x{sc.camera.height} in {seconds['total']:.2f} s "
               f"(load {t_load:.2f}, resample {seconds['resample']:.2f}, propagate {seconds['propagate']:.2f} "
               f"[{walked}]"
               + (f", diffusion {seconds['diffusion']:.2f}" if sc.method.isotropic == "diffusion" else "")
               + f", render {t_render:.2f})")


def _why_black(sc, info) -> str:
    """The likeliest reason a render with the medium in view is black, for its warning."""
    import numpy as np
    if not info["domains"] or not any(np.any(np.asarray(light.power) > 0) for light in sc.lights):
        return "no light has power (every light's irradiance, intensity or radiance is 0)"
    if not np.any(np.asarray(sc.medium.albedo) > 0):
        return f"{sc.medium.source}: medium.albedo = 0, so the medium absorbs all light and scatters none"
    return "are the lights' irradiance or intensity 0, or do they miss the medium?"


def _render_frames(seq, scene, output, exr, width, height, stats, frames, video, workers, scheduler, warm_start,
                   knobs: dict) -> None:
    """``popvol render`` of frames: popvol.sequence.render_sequence with a progress bar over the
    frames, a line per frame, and --video / --stats (with the flicker figure) at the end."""
    from .io.files import write_text_atomically
    from . import sequence as sq
    frame_list = seq.resolve_frames(frames, "--frames", "popvol render")
    if len(frame_list) > 1 and not sq.has_pattern(output):
        raise PopvolError(f"-o/--output {output}: {seq.source} has {len(frame_list)} frames "
                          f"({sq.frames_text(frame_list)}); name the images with a run of # for the frame number "
                          "(e.g. -o out/frame_####.png), or render one frame with --frames N")
    sq.check_patterns(output, exr, frame_list)
    _check_outputs({"--stats": (stats, (".json",)), "--video": (video, (".mp4",))}, [scene] if scene else [])
    if video:
        sq.import_video_writer()                     # before any work: a missing extra is one line
    if workers is not None and scheduler is not None:
        raise PopvolError("--workers and --scheduler exclude each other: a local cluster or a running one")
    cores = os.cpu_count() or 1
    if workers is not None and not 1 <= workers <= cores:
        raise PopvolError(f"--workers {workers} must be in [1, {cores}]: this machine's cores (more local workers "
                          "than cores only compete for them; --scheduler uses a cluster of other machines)")
    if workers is not None:
        workers = min(workers, len(frame_list))       # a worker per run of frames, at most one run a frame
    client = None
    if workers is not None or scheduler is not None:
        try:
            from . import distributed
        except ImportError as e:
            raise PopvolError(f"--workers/--scheduler need popvol.distributed and Dask ({e}); "
                              "pip install 'popvol[distributed]'") from None
        client = distributed.local_client(workers) if workers is not None else distributed.connect(scheduler)
    overrides = {"width": width, "height": height, **knobs}
    t0 = time.perf_counter()
    warnings = {}

    def report(r):
        for w in r.get("warnings", []):
            warnings.setdefault(w.split(": ", 1)[-1] if w.startswith("frame ") else w, w)
        click.echo(_frame_line(r))

    if client is not None:          # popvol.distributed shows its own progress bar over frames
        try:
            results = sq.render_sequence(scene, frame_list, output, client=client, warm_start=warm_start, exr=exr,
                                         **overrides)
        finally:
            client.close()          # a local cluster closes with its client; a remote one stays up
        for r in results:
            report(r)
    else:
        with _progress() as bar:
            task = bar.add_task("frames", total=len(frame_list), info="")

            def on_frame(r):
                bar.advance(task)
                bar.update(task, info=f"frame {r['frame']}" + (" (skipped)" if r["skipped"] else ""))
                report(r)

            results = sq.render_sequence(scene, frame_list, output, warm_start=warm_start, exr=exr,
                                         progress=on_frame, **overrides)
    for w in warnings.values():
        click.echo(f"popvol: warning: {w}", err=True)
    sc = seq.scene(frame_list[0], **{k: v for k, v in overrides.items() if v is not None})
    exposures = sorted({r["exposure"] for r in results if r["exposure"] is not None})
    stops_video = None
    if video:
        stops_video = sq.write_video(video, results, sq.video_fps(seq.fps, frame_list), sc.method.exposure,
                                     sc.method.tone)
        click.echo(f"{video}: {len(results)} frames at {sq.video_fps(seq.fps, frame_list):g} fps")
    total = time.perf_counter() - t0
    rendered = [r for r in results if not r["skipped"]]
    if stats:
        flick = sq.flicker(scene, results, stops_video, **{k: v for k, v in overrides.items() if v is not None})
        doc = {"scene": sc.source, "frames": results, "width": sc.camera.width, "height": sc.camera.height,
               "fps": seq.fps, "method": vars(sc.method), "warm_start": warm_start,
               "exposure": {"setting": sc.method.exposure,
                            "stops": exposures[0] if len(exposures) == 1 else exposures,
                            "metered_frame": results[0].get("metered_frame") if results else None,
                            "video_stops": stops_video},
               "flicker": flick,
               "seconds": {"total": total, "rendered_frames": len(rendered),
                           "mean_per_rendered_frame": (sum(r["seconds"]["total"] for r in rendered) / len(rendered)
                                                       if rendered else None)}}
        try:
            write_text_atomically(stats, json.dumps(_json_safe(sq._json_safe(doc)), indent=2, allow_nan=False))
        except OSError as e:
            raise PopvolError(f"--stats {stats}: cannot write ({e.strerror or e})") from None
    click.echo(f"{len(results)} frame{'s' if len(results) != 1 else ''} ({sq.frames_text(frame_list)}) in "
               f"{total:.1f} s: {len(rendered)} rendered, {len(results) - len(rendered)} skipped "
               "(already written for this scene and method)"
               + (f", one exposure {exposures[0]:+.2f} stops" if len(exposures) == 1 else ""))


def _frame_line(r: dict) -> str:
    """One line about a rendered (or skipped) frame."""
    if r["skipped"]:
        return f"{r['path']}: frame {r['frame']} skipped (already written for this scene and method)"
    s = r["seconds"]
    return (f"{r['path']}: frame {r['frame']} in {s['total']:.2f} s (propagate {s.get('propagate', 0):.2f} "
            f"[{', '.join(map(str, r['iterations']))} iterations], diffusion {s.get('diffusion', 0):.2f}, "
            f"render {s.get('render', 0):.2f})" + (" [medium clipped]" if r.get("hidden") else ""))


@cli.command()
@click.option("--json", "json_out", type=click.Path(dir_okay=False, allow_dash=True),
              help="Write the figures as JSON ('-': to stdout, the tables then go to stderr).")
@click.option("--repeat", type=click.IntRange(min=1, max=1000), default=None,
              help="Timed runs per figure, after a warm-up (default 5; 2 with --quick).")
@click.option("--data", type=click.Path(exists=True, file_okay=False),
              help="Folder holding the WDAS volume (wdas_cloud_sixteenth_dense.npz, in it or in "
                   "its npz/); default $POPVOL_DATA, else ../shared/data/volumes.")
@click.option("--quick", is_flag=True, help="Small sizes and 2 runs (a smoke test, not comparable figures).")
def bench(json_out, repeat, data, quick):
    """Measure propagation and render throughput and each scene's time per stage: min / median
    / max over repeated runs, with peak memory and the machine."""
    from rich.console import Console
    from .bench import print_report, run_benchmarks
    from .io.files import write_text_atomically
    if json_out != "-":
        _check_outputs({"--json": (json_out, (".json",))}, [])
    results = run_benchmarks(quick=quick, repeat=repeat, data=data, echo=lambda s: click.echo(s, err=True))
    text = json.dumps(_json_safe(results), indent=2, allow_nan=False)
    to_stderr = json_out == "-"
    console = Console(stderr=to_stderr, width=None if (sys.stderr if to_stderr else sys.stdout).isatty() else 160)
    print_report(results, console)
    if json_out == "-":
        click.echo(text)
    elif json_out:
        write_text_atomically(json_out, text)


@cli.command("hg-figure")
@click.option("-o", "--output", default="supplement_fig1.png", show_default=True)
def hg_figure(output):
    """Plot f_hg and 2 pi F_hg for g = 0, 0.5, 0.9 (the supplement's Fig. 1)."""
    from .hg import plot_supplement_figure
    _check_outputs({"-o/--output": (output, (".png", ".pdf", ".svg"))}, [])
    plot_supplement_figure(output)
    click.echo(output)


@cli.command()
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Reference image (.exr).")
@click.option("--spp", type=int, default=256, show_default=True, help="Samples per pixel to add.")
@click.option("--passes", type=int, default=4, show_default=True, help="Passes to split them into (>= 2 for a noise estimate; --spp must be a multiple of it, and more passes than samples are cut to one sample each).")
@click.option("--variant", type=click.Choice(["scalar_rgb", "llvm_ad_rgb"]), default="scalar_rgb", show_default=True)
@click.option("--max-depth", type=int, default=1024, show_default=True, help="Longest light path (volpath).")
@click.option("--width", type=int, help="Image width (overrides the scene).")
@click.option("--height", type=int, help="Image height (overrides the scene).")
@click.option("--new", is_flag=True, help="Start over instead of adding to an existing reference.")
def reference(scene, output, spp, passes, variant, max_depth, width, height, new):
    """Render an unbiased reference of SCENE with Mitsuba 3 (volpath), adding to OUTPUT if it exists."""
    from .reference import render_reference
    from .scene import load_scene
    if Path(output).suffix.lower() != ".exr":
        raise PopvolError(f"-o/--output {output}: a reference is stored as .exr")
    outputs = {"-o/--output": (output, (".exr",)), "its metadata": (output + ".json", (".json",)),
               "its per-pixel sums": (output + ".npz", (".npz",))}
    _check_outputs(outputs, [scene] if scene else [])
    sc = load_scene(scene, width=width, height=height)
    _check_outputs(outputs, sc.files)
    with _progress() as bar:
        task = bar.add_task("Mitsuba passes", total=passes, info=f"{spp} spp, {variant}")
        ref = render_reference(sc, output, spp, variant, passes, max_depth, resume=not new,
                               progress=lambda p, n: bar.update(task, completed=p))
    from .metrics import medium_mask
    noise = ref.noise_relmse(medium_mask(ref.image, sc))
    click.echo(f"{output}: {sc.camera.width}x{sc.camera.height}, {ref.spp} spp in {ref.passes} passes, "
               f"{ref.meta['seconds']:.1f} s of Mitsuba" +
               (f", noise relMSE {_fmt(noise, '.2g')} (medium pixels)" if noise is not None else ""))


@cli.command()
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@click.option("--reference", "ref_path", required=True, type=click.Path(dir_okay=False), help="Reference .exr (from popvol reference).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the metrics as JSON.")
@click.option("--figure", type=click.Path(dir_okay=False),
              help="Write popvol | reference | error map | brightness-ratio map as PNG.")
@method_options("compare")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Also write popvol's image (.png/.exr).")
def compare(scene, ref_path, json_out, figure, output, **knobs):
    """Render SCENE with popvol and measure it against a reference image.

    On the pixels whose camera ray crosses the medium (optical depth > 0.01): relMSE with
    eps = 0.01 (mean reference luminance there)^2, unchanged when both images are scaled; the
    brightness ratio popvol / reference there and in the reference's dimmest 50 %, middle 40 %
    and brightest 10 % of them (ranked on one independent half of the reference's passes and
    measured on the other, where it has them, so that its noise does not pick the pixels); the
    reference's own noise in the same relMSE; where the reference has two independent halves,
    the relMSE against a noiseless reference, extrapolated from the relMSE against the
    reference and against each half (a mean of P passes adds about c / P); and the equal-error
    speed-up: the samples per pixel, and seconds at the reference's recorded rate, that the
    reference would need for its noise to equal popvol's error, over popvol's time. A reference
    whose metadata records another scene (its path_traced_digest) is refused."""
    from . import metrics
    from .io.images import write_image
    from . import solve
    from .reference import check_reference_scene, load_reference
    from .renderer import render as render_image
    from .scene import load_scene
    from .io.files import write_text_atomically
    outputs = {"--json": (json_out, (".json",)), "--figure": (figure, (".png",)),
               "-o/--output": (output, (".png", ".exr"))}
    # the reference and its sidecars (popvol reference's REF.exr.json and REF.exr.npz) are inputs
    references = {ref_path: "the reference", ref_path + ".json": "the reference's metadata",
                  ref_path + ".npz": "the reference's per-pixel sums"}
    _check_outputs(outputs, [scene] if scene else [], references)
    ref = load_reference(ref_path)
    h, w = ref.image.shape[:2]
    sc = load_scene(scene, width=w, height=h, **_method_overrides("compare", knobs))
    check_reference_scene(ref_path, ref.meta, sc)
    _check_outputs(outputs, sc.files, references)
    t0 = time.perf_counter()
    solution = solve(sc)
    img = render_image(sc, solution)
    seconds = time.perf_counter() - t0
    mask = metrics.medium_mask(ref.image, sc)
    res = {"scene": sc.source, "reference": str(ref_path), "reference_spp": ref.spp, "method": vars(sc.method),
           "popvol_seconds": seconds, "solve_seconds": solution.seconds,
           "reference_seconds": float(ref.meta.get("seconds", 0.0)) or None,
           "mask": f"camera ray optical depth > {metrics.MASK_OPTICAL_DEPTH:g}",
           **metrics.compare(img, ref.image, mask, ref.variance, ref.halves, ref.half_passes)}
    # popvol's error against the truth and the reference's noise: extrapolated from the reference's
    # halves where it has them, else the relMSE less the variance's estimate of the noise
    if res["relmse_extrapolated"] is not None:
        error, noise = res["relmse_extrapolated"], res["reference_noise_observed"]
    else:
        noise = res["reference_noise_relmse"]
        error = None if noise is None else res["relmse"] - noise
    res["equal_error"] = metrics.equal_error(error, noise, ref.spp, res["reference_seconds"], seconds)
    if json_out:
        write_text_atomically(json_out, json.dumps(_json_safe(res), indent=2, allow_nan=False))
    if figure:
        metrics.comparison_figure(figure, img, ref.image, sc.method.exposure,
                                  f"{Path(sc.source).name}: {_method_label(sc.method)}, "
                                  f"{sc.method.resolution} cells, reference {ref.spp} spp", mask=mask,
                                  tone=sc.method.tone)
    if output:
        write_image(output, img, sc.method.exposure, sc.method.tone)
    if res["mask_pixels"] == 0:
        click.echo("popvol: warning: no camera ray crosses the medium; the relative metrics are n/a", err=True)
    capped = solution.medium.capped_scattering_warning()     # the grid it was solved on
    if capped:
        click.echo(f"popvol: warning: {capped}", err=True)
    b = res["brightness_bands"]
    flip = res["flip"]
    click.echo(f"relMSE {_fmt(res['relmse'], '.4g')} on {res['mask_pixels']} medium pixels  "
               f"brightness x{_fmt(res['brightness_ratio'], '.3f')} (dim 50 % x{_fmt(b['dim'], '.3f')}, "
               f"mid 40 % x{_fmt(b['mid'], '.3f')}, bright 10 % x{_fmt(b['bright'], '.3f')}"
               f"{'' if ref.halves is not None else '; bands ranked on the reference itself: it has no independent halves'})  "
               f"reference noise {_fmt(res['reference_noise_relmse'], '.2g')}  "
               f"SSIM {_fmt(res['ssim'], '.3f')}  FLIP {_fmt(flip, '.3f')}  popvol {seconds:.2f} s")
    if res["relmse_extrapolated"] is not None:
        click.echo(f"relMSE against a noiseless reference {_fmt(res['relmse_extrapolated'], '.4g')} (extrapolated "
                   f"from the reference's {ref.passes} passes and its two halves; its noise adds "
                   f"{_fmt(res['reference_noise_observed'], '.2g')} to the relMSE above)")
    eq = res["equal_error"]
    if eq["seconds"] is not None:
        click.echo(f"equal error: the reference would need {eq['spp']:.3g} spp, {eq['seconds']:.3g} s at its "
                   f"measured {res['reference_seconds'] / ref.spp:.3g} s per spp: x{_fmt(eq['speedup'], '.3g')} popvol's time")
    elif eq["spp"] is not None:
        click.echo(f"equal error: the reference would need {eq['spp']:.3g} spp (its render time is not recorded)")
    else:
        click.echo("equal error: n/a (the reference has no noise estimate, or is too noisy to show popvol's error)")


def _fmt(value, spec: str) -> str:
    """``value`` formatted, or 'n/a' for None or NaN."""
    return "n/a" if value is None or not math.isfinite(value) else format(value, spec)


def _json_safe(value):
    """``value`` with NaN and inf floats as None (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@cli.command()
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@click.option("--port", type=int, default=8765, show_default=True, help="Port to listen on (0: any free port).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to bind. Anything but a loopback address exposes the viewer to your network.")
@click.option("--no-browser", is_flag=True, help="Only print the address (headless use).")
@click.option("--width", type=int, help="Full view width in pixels (default: the scene's).")
@click.option("--height", type=int, help="Full view height in pixels (default: the scene's).")
@click.option("--resolution", type=int, default=64, show_default=True,
              help="Cells along the longest side of each light domain in the view (at most the scene's; saved in the TOML).")
@click.option("--draft-resolution", type=int, default=32, show_default=True,
              help="Cells of the domains propagated while the light or medium is being dragged.")
@click.option("--save-dir", type=click.Path(file_okay=False), default=".", show_default=True,
              help="Folder where the page's Save button writes popvol-view-NNN.png and .toml.")
def view(scene, port, host, no_browser, width, height, resolution, draft_resolution, save_dir):
    """Interactive viewer in the browser: orbit the camera, move the sun, change the medium."""
    try:
        import starlette  # noqa: F401
        import tomli_w  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as e:
        raise PopvolError(f"popvol view needs the viewer extra ({e.name} is missing): "
                          "pip install 'popvol[viewer]'") from None
    from .viewer.engine import Engine
    from .viewer.server import serve
    from .io.files import folder_problem
    if problem := folder_problem(save_dir):
        raise PopvolError(f"--save-dir {save_dir}: folder {problem}")
    engine = Engine(scene, width=width, height=height, resolution=resolution, draft_resolution=draft_resolution)
    serve(engine, host, port, open_browser=not no_browser, save_dir=save_dir, echo=click.echo)


def _method_label(method) -> str:
    """'default method', or the knobs that differ from it and change the image (not
    ``resolution``, which the title gives apart, nor the PNG's ``exposure`` and ``tone``)."""
    changes = {k.name: getattr(method, k.name) for k in KNOBS if getattr(method, k.name) != k.default
               and k.name not in ("resolution", "exposure", "tone")}
    return ", ".join(f"{k} = {v}" for k, v in changes.items()) if changes else "default method"


def _check_writable(path: str, option: str) -> None:
    from .io.files import folder_problem
    parent = Path(path).resolve().parent
    if problem := folder_problem(parent):
        raise PopvolError(f"{option} {path}: folder {parent} {problem}")
    if Path(path).is_dir():
        raise PopvolError(f"{option} {path}: is a folder, not a file")
    from .io.files import check_writable_folder
    check_writable_folder(parent, f"{option} {path}")


def _check_outputs(outputs: dict, inputs, other_inputs: dict | None = None) -> None:
    """Before any work: each output (option -> (path or None, allowed suffixes)) has an allowed
    suffix, a folder to go in, and is neither an input file nor another output. ``inputs``: the
    scene's files; ``other_inputs``: other input files, path -> what it is ("the reference")."""
    seen = {Path(p).resolve(): "the scene's input file " + str(p) for p in inputs}
    for p, what in (other_inputs or {}).items():
        seen.setdefault(Path(p).resolve(), f"{what}, {p}")
    for option, (path, suffixes) in outputs.items():
        if path is None:                  # not given ("" is given, and has no suffix)
            continue
        if str(path).endswith(("/", os.sep)):
            raise PopvolError(f"{option} {path}: names a folder (it ends in {str(path)[-1]}); give a file name")
        if Path(path).suffix.lower() not in suffixes:
            raise PopvolError(f"{option} {path}: must end in {' or '.join(suffixes)}")
        _check_writable(path, option)
        resolved = Path(path).resolve()
        if resolved in seen:
            raise PopvolError(f"{option} {path} is {seen[resolved]}; writing it would overwrite it")
        seen[resolved] = f"also the output of {option}"


def main(argv=None) -> None:
    try:
        rv = cli.main(args=argv, prog_name="popvol", standalone_mode=False)
    except PopvolError as e:
        click.echo(f"popvol: error: {e}", err=True)
        sys.exit(2)
    except click.ClickException as e:     # a bad option or argument: one line, as every other error
        ctx = getattr(e, "ctx", None)
        where = f"{ctx.command_path}: " if ctx is not None else ""
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        click.echo(f"popvol: error: {where}{e.format_message()}{hint}", err=True)
        sys.exit(e.exit_code)
    except click.exceptions.Abort:
        click.echo("popvol: interrupted", err=True)
        sys.exit(130)
    except OSError as e:                  # a file that cannot be written or read (full disk, quota)
        where = f"{e.filename}: " if e.filename else ""
        click.echo(f"popvol: error: {where}{e.strerror or e}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        click.echo("popvol: interrupted", err=True)
        sys.exit(130)
    sys.exit(rv if isinstance(rv, int) else 0)


if __name__ == "__main__":
    main()
