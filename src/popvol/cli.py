"""Command line: ``popvol render``, ``popvol bench``, ``popvol hg-figure``.

Bad input ends with one line ``popvol: error: ...`` on stderr and exit status 2, never a
traceback.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import click

from .errors import PopvolError


def _progress():
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                    TimeElapsedColumn(), transient=True, disable=not sys.stderr.isatty())


@click.group()
@click.version_option(package_name="popvol")
def cli():
    """popvol: multiple scattering in clouds and smoke by Principal-Ordinate Propagation."""


@cli.command()
@click.argument("scene", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", default="cloud.png", show_default=True, help="Image to write (.png or .exr).")
@click.option("--exr", type=click.Path(dir_okay=False), help="Also write the linear HDR image as EXR.")
@click.option("--width", type=int, help="Image width in pixels (overrides the scene).")
@click.option("--height", type=int, help="Image height in pixels (overrides the scene).")
@click.option("--resolution", type=int, help="Cells along the longest side of each light domain.")
@click.option("--solver", type=click.Choice(["sweep", "jacobi"]), help="Propagation solver.")
@click.option("--rule", type=click.Choice(["moment", "paper"]), help="Outgoing-anisotropy rule.")
@click.option("--decay", type=click.Choice(["poisson", "paper"]), help="Anisotropy decay law.")
@click.option("--spp", type=int, help="Jittered samples per pixel.")
@click.option("--exposure", type=float, help="PNG exposure in stops.")
@click.option("--stats", type=click.Path(dir_okay=False), help="Write timings, iterations and energy budget as JSON.")
def render(scene, output, exr, width, height, resolution, solver, rule, decay, spp, exposure, stats):
    """Render SCENE (a TOML file; the built-in demo cloud if omitted) to an image."""
    from .io.images import write_image
    from .propagate import solve
    from .render import render as render_image
    from .scene import load_scene

    _check_writable(output, "-o/--output")
    if exr:
        _check_writable(exr, "--exr")
    if stats:
        _check_writable(stats, "--stats")
    t0 = time.perf_counter()
    sc = load_scene(scene, width=width, height=height, resolution=resolution, solver=solver,
                    rule=rule, decay=decay, spp=spp, exposure=exposure)
    t_load = time.perf_counter() - t0
    tol = sc.method.tolerance
    with _progress() as bar:
        tasks = {}

        def on_progress(light, it, residual):
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
    write_image(output, img, sc.method.exposure)
    if exr:
        write_image(exr, img)
    t_write = time.perf_counter() - t2
    seconds = {"load": t_load, **solution.seconds, "render": t_render, "write": t_write,
               "total": time.perf_counter() - t0}
    info = solution.stats()
    for d in info["domains"]:
        if not d["converged"]:
            click.echo(f"popvol: warning: light {d['light']} stopped after {d['iterations']} iterations "
                       f"with {d['residual']:.1e} of its energy still in flight (tolerance {tol:g}); "
                       "raise method.max_iterations for a converged image", err=True)
    if stats:
        doc = {"scene": sc.source, "image": str(output), "width": sc.camera.width, "height": sc.camera.height,
               "method": vars(sc.method), "seconds": seconds, "domains": info["domains"]}
        Path(stats).write_text(json.dumps(doc, indent=2))
    its = ", ".join(str(d["iterations"]) for d in info["domains"])
    click.echo(f"{output}: {sc.camera.width}x{sc.camera.height} in {seconds['total']:.2f} s "
               f"(load {t_load:.2f}, resample {seconds['resample']:.2f}, propagate {seconds['propagate']:.2f} "
               f"[{sc.method.solver}, {its} iterations], render {t_render:.2f})")


@cli.command()
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the figures as JSON.")
@click.option("--quick", is_flag=True, help="Fewer repetitions (for smoke tests).")
def bench(json_out, quick):
    """Measure propagation and render throughput and the demo's end-to-end time."""
    from .bench import run_benchmarks
    if json_out:
        _check_writable(json_out, "--json")
    results = run_benchmarks(quick=quick, echo=lambda s: click.echo(s, err=True))
    text = json.dumps(results, indent=2)
    if json_out:
        Path(json_out).write_text(text)
    click.echo(text)


@cli.command("hg-figure")
@click.option("-o", "--output", default="supplement_fig1.png", show_default=True)
def hg_figure(output):
    """Plot f_hg and 2 pi F_hg for g = 0, 0.5, 0.9 (the supplement's Fig. 1)."""
    from .hg import plot_supplement_figure
    _check_writable(output, "-o/--output")
    plot_supplement_figure(output)
    click.echo(output)


def _check_writable(path: str, option: str) -> None:
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise PopvolError(f"{option} {path}: folder {parent} does not exist")


def main(argv=None) -> None:
    try:
        rv = cli.main(args=argv, prog_name="popvol", standalone_mode=False)
    except PopvolError as e:
        click.echo(f"popvol: error: {e}", err=True)
        sys.exit(2)
    except click.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except click.exceptions.Abort:
        click.echo("popvol: aborted", err=True)
        sys.exit(1)
    except KeyboardInterrupt:
        click.echo("popvol: interrupted", err=True)
        sys.exit(130)
    sys.exit(rv if isinstance(rv, int) else 0)


if __name__ == "__main__":
    main()
