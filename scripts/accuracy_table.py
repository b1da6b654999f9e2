"""Write docs/ACCURACY.md: the default method (eighteen ordinates) and the one-lobe walk alone
against Mitsuba 3 references on the accuracy suite, at 64, 128 and 256 cells, in the metric of
``popvol compare`` (with, for the notes, the one-lobe sweeps with their diffusion stage and the
six-ordinate walk at every resolution, the default without the gathered last bounce at 64 and 128
cells, the one-lobe Jacobi wavefront at 128 and the binned one at 64); each row also against a
noiseless reference, extrapolated from the reference's two halves
(``metrics.extrapolated_relmse``), which the goal is held against. Run from the repository root,
with ../shared beside the checkout (about 10 minutes on 2 cores once the references exist):

    python scripts/accuracy_table.py [--spp 4096] [--variant llvm_ad_rgb]

The suite:
- every scene of scenes/accuracy/ (the WDAS cloud under the sun at five scattering angles and at
  three densities, a thin haze, the procedural cumulus field with the sun behind the camera and
  behind the field, the dense smoke under a sun and a point light, a cloud under an HDR map). Their references are
  build/accuracy/NAME.exr (not in git), rendered here with ``popvol.reference`` when missing or
  short of ``--spp`` (times SPP_SCALE for the scenes that cost Mitsuba far more per sample) and
  extended, never edited, on later runs; a reference made before ``popvol reference`` kept two
  independent halves of its passes is extended by half its samples, which form one of them;
- the gallery's scenes that the suite has no copy of (examples/NAME.toml; references
  build/gallery/NAME_ref.exr, made as docs/GALLERY.md says; skipped, with the reason, without one).

A scene whose volume is not in ../shared is skipped with the reason. ``resolution`` is varied;
a sky's or an HDR map's domains keep ``environment_resolution`` (64) at every row, so only the sun's
domain is refined there.
Each scene gets a figure of the default at 128 cells (popvol | reference | relative error |
the ratio map popvol / reference) in docs/figures/accuracy/.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from PIL import Image

import popvol
from popvol import metrics
from popvol.errors import PopvolError
from popvol.reference import load_reference, render_reference

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "scenes" / "accuracy"
BUILD = ROOT / "build" / "accuracy"
GALLERY_REFS = ROOT / "build" / "gallery"
FIGURES = ROOT / "docs" / "figures" / "accuracy"
#: scenes/accuracy, in the order of the table, and what each varies
ORDER = {
    "wdas_angle_000": "sun behind the cloud (scattering angle ~0 degrees)",
    "wdas_angle_045": "scattering angle ~45 degrees",
    "wdas_angle_090": "scattering angle ~90 degrees (sun from the side)",
    "wdas_angle_135": "scattering angle ~135 degrees",
    "wdas_angle_180": "sun behind the camera (~180 degrees)",
    "wdas_density_0.1": "density x0.1, 90 degrees",
    "wdas_density_10": "density x10, 90 degrees",
    "haze": "optically thin cloud (tau ~1), sun",
    "field_sun": "14 small cumulus on voxels twice as tall as wide, ~135 degrees",
    "field_silver": "the same field, the sun low behind it (~35 degrees): silver linings",
    "smoke1": "dense smoke, sun",
    "smoke1_point": "smoke lit by a point light",
    "demo_envmap": "cloud under an HDR environment map",
}
#: the gallery's scenes (docs/GALLERY.md) that the suite has no copy of, against its references
GALLERY = {
    "wdas_side": "gallery: sun from the side + sky",
    "wdas_front": "gallery: sun behind the camera + sky",
    "wdas_silver": "gallery: sun behind the cloud + sky",
    "dragon_sky": "gallery: dragon, sun + sky",
    "demo_dusk": "gallery: cumulus at dusk, sun + sky",
}
#: references of these scenes get this share of --spp: the dense smoke and the densest WDAS cost
#: Mitsuba ~10x more per sample than the others; the haze is thin and converges fast
SPP_SCALE = {"smoke1": 0.125, "wdas_density_10": 0.125, "haze": 0.5}
RESOLUTIONS = (64, 128, 256)
#: (label, method overrides, resolutions): the default (eighteen ordinates) and the one-lobe walk
#: alone at every resolution; for the notes, the one-lobe sweeps with their diffusion stage at
#: every resolution, the default without the gathered last bounce at 64 and 128 cells, the one-lobe
#: Jacobi wavefront at 128 and the binned one at 64 (docs/METHOD.md, "Six ordinates", "Gathered
#: last bounce", "The schedule", "The merge itself"), and the six-ordinate walk at every resolution
#: ("Six ordinates")
VARIANTS = (("default", {}, RESOLUTIONS), ("walk alone", {"solver": "sweep", "isotropic": "walk"}, RESOLUTIONS),
            ("one-lobe sweeps", {"solver": "sweep"}, RESOLUTIONS),
            ("six ordinates", {"ordinates": 6}, RESOLUTIONS),
            ("no gather", {"gather": 0}, (64, 128)),
            ("jacobi", {"solver": "jacobi"}, (128,)), ("binned", {"solver": "binned"}, (64,)))
GOAL = {"relmse": 0.03, "band": 0.05, "drift": 0.02}


def measure(path: Path, ref, overrides: dict, resolution: int) -> tuple[dict, object]:
    """popvol's image of ``path`` at the reference's size and its comparison with ``ref``."""
    h, w = ref.image.shape[:2]
    scene = popvol.load_scene(path, width=w, height=h, resolution=resolution, **overrides)
    t0 = time.perf_counter()
    image = popvol.render(scene, popvol.solve(scene))
    seconds = time.perf_counter() - t0
    c = metrics.compare(image, ref.image, metrics.medium_mask(ref.image, scene), ref.variance, ref.halves,
                        ref.half_passes)
    return {"cells": resolution, "seconds": seconds, **c}, image


def error(r: dict) -> float:
    """popvol's relMSE against a noiseless reference (metrics.extrapolated_relmse), or against the
    reference where it has no halves to extrapolate from."""
    return r["relmse"] if r["relmse_extrapolated"] is None else r["relmse_extrapolated"]


def row(label: str, r: dict) -> str:
    b = r["brightness_bands"]
    return (f"| {label} | {r['cells']} | {r['relmse']:.3f} | {error(r):.3f} | x{r['brightness_ratio']:.3f} | "
            f"x{b['dim']:.3f} / x{b['mid']:.3f} / x{b['bright']:.3f} | {r['seconds']:.1f} s |")


def drift(a: dict, b: dict) -> float:
    """The largest change of a band's brightness ratio between two rows, as a fraction."""
    return max(abs(b["brightness_bands"][k] / a["brightness_bands"][k] - 1.0) for k in ("dim", "mid", "bright"))


def goal_met(r128: dict, r256: dict) -> bool:
    bands = r256["brightness_bands"].values()
    return (error(r256) <= GOAL["relmse"] and all(abs(v - 1.0) <= GOAL["band"] for v in bands)
            and drift(r128, r256) <= GOAL["drift"])


def reference_for(key: str, path: Path, ref_path: Path, spp: int, variant: str):
    """The reference of a suite scene, rendered or extended to ``spp`` if it has fewer."""
    ref = load_reference(ref_path) if ref_path.exists() else None
    if ref is None or ref.spp < spp:
        more = spp - (ref.spp if ref else 0)
        # a reference is extended with passes of its own size (popvol.reference requires it)
        passes = 8 if ref is None else max(1, more // ref.meta["spp_per_pass"])
        print(f"{key}: reference, {more} spp ...", flush=True)
        ref = render_reference(popvol.load_scene(path), ref_path, more, variant, passes=passes)
    if ref.halves is None:                      # made before the halves were kept
        return extend_by_half(key, path, ref_path, ref)
    return ref


def extend_by_half(key: str, path: Path, ref_path: Path, ref):
    """A reference without two independent halves (``Reference.halves``), extended by half its
    passes at its own samples per pass and size: the new passes form one half."""
    passes = max(1, ref.passes // 2)
    print(f"{key}: reference, {passes} more passes for its independent half ...", flush=True)
    h, w = ref.image.shape[:2]
    return render_reference(popvol.load_scene(path, width=w, height=h), ref_path, ref.meta["spp_per_pass"] * passes,
                            ref.meta.get("variant", "llvm_ad_rgb"), passes=passes,
                            max_depth=ref.meta.get("max_depth", 1024))


def small_png(path: Path) -> None:
    """Rewrite a figure as a 256-colour PNG (a quarter of the bytes; the figures are plots)."""
    with Image.open(path) as im:
        small = im.convert("RGB").quantize(256)
    small.save(path, optimize=True)


def scene_section(key: str, what: str, path: Path, ref) -> tuple[list[str], dict]:
    """The lines of one scene's section and its summary figures."""
    h, w = ref.image.shape[:2]
    mask = metrics.medium_mask(ref.image, popvol.load_scene(path, width=w, height=h))
    noise = ref.noise_relmse(mask)
    table = ["| method | cells | relMSE | against a noiseless reference | brightness | dim / mid / bright | "
             "solve + render |",
             "|---|---|---|---|---|---|---|"]
    rows = {}
    for label, overrides, resolutions in VARIANTS:
        for n in resolutions:
            r, image = measure(path, ref, overrides, n)
            rows[label, n] = r
            table.append(row(label, r))
            print(key, row(label, r), flush=True)
            if label == "default" and n == 128:
                fig = FIGURES / f"{key.replace('/', '_')}.png"
                metrics.comparison_figure(fig, image, ref.image, "auto", f"{key}: default, 128 cells", mask=mask)
                small_png(fig)
    observed = rows["default", 128]["reference_noise_observed"]
    adds = "" if observed is None else f"; what its noise adds to the default's relMSE at 128 cells {observed:.3g}"
    lines = [f"## {key}", "", f"`{path.relative_to(ROOT)}`: {what}. {w}x{h}; reference {ref.spp} spp in "
             f"{ref.passes} passes, its own noise relMSE {noise:.3g} from its variance{adds}; "
             f"{int(mask.sum())} medium pixels.", "", *table,
             "", f"![{key}](figures/accuracy/{key.replace('/', '_')}.png)", ""]
    return lines, {"noise": noise, "observed": observed, "spp": ref.spp, "rows": rows}


def summary_row(key: str, s: dict) -> str:
    rows = s["rows"]
    d = [rows["default", n] for n in RESOLUTIONS]
    o = [rows["one-lobe sweeps", n] for n in RESOLUTIONS]
    e = [rows["six ordinates", n] for n in RESOLUTIONS]
    b = d[-1]["brightness_bands"]
    observed = "n/a" if s["observed"] is None else f"{s['observed']:.3f}"
    return (f"| {key} | {s['noise']:.3f} / {observed} | " + " / ".join(f"{r['relmse']:.3f}" for r in d)
            + " | " + " / ".join(f"{error(r):.3f}" for r in d)
            + f" | x{b['dim']:.2f} / x{b['mid']:.2f} / x{b['bright']:.2f} | {100 * drift(d[1], d[2]):.1f} % | "
            f"{rows['walk alone', 128]['relmse']:.3f} | " + " / ".join(f"{r['relmse']:.3f}" for r in o)
            + f" (x{o[1]['brightness_ratio']:.2f}) | {rows['no gather', 128]['relmse']:.3f} "
            f"(x{rows['no gather', 128]['brightness_ratio']:.2f}) | {rows['jacobi', 128]['relmse']:.3f} | "
            f"{rows['binned', 64]['relmse']:.3f} | " + " / ".join(f"{error(r):.3f}" for r in e)
            + f" (x{e[1]['brightness_ratio']:.2f}) | {'yes' if goal_met(d[1], d[2]) else 'no'} |")


def means(measured: list[dict]) -> list[str]:
    """A line of the mean and median relMSE over the scenes, per variant and resolution (with
    ``--only``, the kept scenes' figures as their sections print them: :func:`kept_sections`)."""
    if not measured:
        return []
    parts = []
    for label, _overrides, resolutions in VARIANTS:
        figs = []
        for n in resolutions:
            v = [rows[label, n]["relmse"] for rows in measured]
            x = [error(rows[label, n]) for rows in measured]
            figs.append(f"{statistics.mean(v):.3f} ({statistics.median(v):.3f}; against a noiseless reference "
                        f"{statistics.mean(x):.3f} ({statistics.median(x):.3f})) at {n}")
        parts.append(f"{label} {', '.join(figs)}")
    return [f"Mean (median) relMSE over the {len(measured)} scenes: " + "; ".join(parts) + ".", ""]


def kept_sections(path: Path) -> dict[str, tuple[list[str], list[str], dict]]:
    """Per scene key, the lines of its section, its summary row(s) and its figures in an
    existing docs/ACCURACY.md (for ``--only``): {(method, cells): {"relmse", "relmse_extrapolated"}}
    read back from its section's table (to 3 decimals, as printed)."""
    lines = path.read_text().splitlines()
    out, key = {}, None
    labels = {label for label, _, _ in VARIANTS}
    for line in lines:
        if line.startswith("_Generated"):
            key = None
        elif line.startswith("## ") and not line.startswith("## Summary"):
            key = line[3:].strip()
            out[key] = ([], [], {})
        if key is not None:
            out[key][0].append(line)
            cells = [c.strip() for c in line.strip("|").split("|")]
            if line.startswith("| ") and cells[0] in labels and cells[1].isdigit():
                out[key][2][cells[0], int(cells[1])] = {"relmse": float(cells[2]),
                                                        "relmse_extrapolated": float(cells[3])}
    for line in lines:
        cells = line.split(" | ")
        if line.startswith("| ") and cells[0][2:] in out:
            out[cells[0][2:]][1].append(line)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=4096, help="samples per pixel of the suite's references")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--only", nargs="+", metavar="SCENE",
                    help="measure only these scenes (keys as in the table, e.g. smoke1_point or "
                         "gallery/wdas_side) and keep every other scene's section and summary row "
                         "from the current docs/ACCURACY.md")
    args = ap.parse_args()
    keep = kept_sections(ROOT / "docs" / "ACCURACY.md") if args.only else None
    BUILD.mkdir(parents=True, exist_ok=True)
    FIGURES.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    cases = [(name, what, SUITE / f"{name}.toml", "suite") for name, what in ORDER.items()]
    cases += [(f"gallery/{name}", what, ROOT / "examples" / f"{name}.toml", "gallery") for name, what in GALLERY.items()]
    if args.only:
        unknown = sorted(set(args.only) - {c[0] for c in cases})
        if unknown:
            ap.error(f"--only: no scene {', '.join(unknown)} in the table")
    body, summary, measured = [], [], []
    for key, what, path, kind in cases:
        if keep is not None and key not in args.only:
            if key not in keep:
                ap.error(f"--only: docs/ACCURACY.md has no section for {key} to keep; run without --only")
            body += keep[key][0]
            summary += keep[key][1]
            if keep[key][2]:
                measured.append(keep[key][2])
            continue
        try:
            if kind == "suite":
                ref = reference_for(key, path, BUILD / f"{key}.exr", int(args.spp * SPP_SCALE.get(key, 1.0)),
                                    args.variant)
            else:
                ref_path = GALLERY_REFS / f"{path.stem}_ref.exr"
                if not ref_path.is_file():
                    raise PopvolError(f"no {ref_path.relative_to(ROOT)} (docs/GALLERY.md says how to make it)")
                ref = load_reference(ref_path)
                if ref.halves is None:
                    ref = extend_by_half(key, path, ref_path, ref)
        except PopvolError as e:
            body += [f"## {key}", "", f"Skipped: {e}", ""]
            print(f"{key}: skipped ({e})", flush=True)
            continue
        lines, s = scene_section(key, what, path, ref)
        body += lines
        summary.append(summary_row(key, s))
        measured.append(s["rows"])
    head = ["# Accuracy against Mitsuba 3", "",
            "Generated by `python scripts/accuracy_table.py`; do not edit. popvol's solve and render at the "
            "reference's size on 2 cores, against Mitsuba 3 `volpath` (max_depth 1024, variant "
            f"{args.variant}) rendered by `popvol.reference` (its conventions are tested in "
            "tests/test_reference.py). The metric is `popvol compare`'s, on the pixels whose camera ray "
            f"crosses the medium (optical depth > {metrics.MASK_OPTICAL_DEPTH:g}): relMSE with epsilon = "
            "0.01 x (mean reference luminance there)^2, unchanged when both images are scaled; the "
            "brightness ratio popvol / Mitsuba there, and the same ratio in the reference's dimmest 50 % "
            "(dim), middle 40 % (mid) and brightest 10 % (bright) of those pixels, each half of the "
            "reference's passes ranked into the bands and measured against the other half (so that the "
            "reference's noise does not pick the pixels it is measured on: `popvol.metrics`); the "
            "reference's own noise in the same metric beside it, and popvol's relMSE against a noiseless "
            "reference, extrapolated from its relMSE against the reference and against each half (a "
            "reference that averages P passes adds about c / P to the relMSE: "
            "`metrics.extrapolated_relmse`; the noise that fit sees, c / P, is the second figure of the "
            "summary's reference noise, beside the estimate from the passes' variance). A sky's or an HDR map's domains keep "
            "`environment_resolution` = 64 at every row. The default walks a sun's and an "
            "environment's light with eighteen ordinates, every order, with no diffusion stage (`solver = "
            "\"ordinates\"`, docs/METHOD.md \"Six ordinates\", \"Eighteen ordinates\"; point lights sweep one lobe with the "
            "diffusion stage) and gathers the last scattering (`gather = 64`, docs/METHOD.md "
            "\"Gathered last bounce\"), and so do the variants but the one without it. Beside the "
            "default: the one-lobe walk alone (`solver = \"sweep\"`, `isotropic = \"walk\"`: the "
            "papers' POP) and the one-lobe sweeps with their diffusion stage (`solver = \"sweep\"`, "
            "the default before the ordinates' walks) at every resolution, the default without the "
            "gather (`gather = 0`, the lobes light the camera) at 64 and 128 cells, the one-lobe "
            "Jacobi wavefront (`solver = \"jacobi\"`) at 128 cells and the binned wavefront (`solver = "
            "\"binned\"`, docs/METHOD.md \"The merge itself\") at 64 (both with the diffusion "
            "stage), and the six-ordinate walk (`ordinates = 6`, the default before eighteen, "
            "docs/METHOD.md \"Six ordinates\") at every resolution, its relMSE against a noiseless reference in the summary; "
            "the other `[experimental]` variants are measured in "
            "[ACCURACY_NOTES.md](ACCURACY_NOTES.md) and docs/METHOD.md.", "",
            f"The goal (#11): relMSE <= {GOAL['relmse']} (against a noiseless reference), every band within "
            f"{100 * GOAL['band']:.0f} % of x1 and no band moving by more than {100 * GOAL['drift']:.0f} % "
            "from 128 to 256 cells, on every scene.", "",
            "## Summary: the default method", "",
            "| scene | reference noise: variance / observed | relMSE at 64 / 128 / 256 cells | against a "
            "noiseless reference | dim / mid / bright at 256 | "
            "largest band move 128 -> 256 | walk alone, relMSE at 128 | one-lobe sweeps, at 64 / 128 / 256 "
            "(brightness at 128) | no gather, at 128 (brightness) | Jacobi, at 128 | binned, at 64 | "
            "six ordinates, against a noiseless reference at 64 / 128 / 256 (brightness at 128) | goal met |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    made = f"_Generated in {time.perf_counter() - t_all:.0f} s._"
    if args.only:
        made = f"_Generated in parts; {', '.join(args.only)} last, in {time.perf_counter() - t_all:.0f} s._"
    text = head + summary + [""] + means(measured) + body + [made]
    out = ROOT / "docs" / "ACCURACY.md"
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(text) + "\n")
    tmp.replace(out)
    print(out)


if __name__ == "__main__":
    main()
