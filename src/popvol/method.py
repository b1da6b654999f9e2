"""The method's knobs, each declared once in :data:`KNOBS`.

Everything else is derived from that table: the :class:`Method` dataclass (fields and
defaults), :meth:`Method.validate`, the keys the scene loader accepts in ``[method]`` and
``[experimental]``, the method options of ``popvol render`` and ``popvol compare``
(:func:`cli_knobs`), the tables of docs/SCENE.md (:func:`knob_table_markdown`) and the tables a
scene file is written with (:func:`method_tables`).

The default method is the product. Experimental knobs select the variants measured in
docs/ACCURACY.md (several of them 2-17x further from Mitsuba than the default); a scene file
sets them in an ``[experimental]`` table, Python code as ``Method`` fields or keyword
arguments of ``load_scene``. The command line does not offer them.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field, make_dataclass

from . import check
from .errors import PopvolError


@dataclass(frozen=True)
class Knob:
    """One method setting.

    name: the ``Method`` field and the scene-file key.
    default: its value when not given; its type (int, float, str) is the knob's type.
    allowed: (lo, hi) for a number, the allowed strings for a string.
    help: one line, for ``--help`` and the start of the docs' meaning column.
    doc: the rest of the docs' meaning column.
    experimental: set in ``[experimental]``, not in ``[method]``; not on the command line.
    zero: 0 is allowed besides [lo, hi] (it means "automatic").
    auto: a number knob whose default is the string "auto", allowed besides [lo, hi].
    cli: the commands (``"render"``, ``"compare"``) that offer ``--name``.
    default_text, allowed_text: what docs/SCENE.md shows instead of the plain default/range.
    """

    name: str
    default: int | float | str
    allowed: tuple
    help: str
    doc: str = ""
    experimental: bool = False
    zero: bool = False
    auto: bool = False
    cli: tuple[str, ...] = ()
    default_text: str = ""
    allowed_text: str = ""

    @property
    def table(self) -> str:
        """The scene-file table the knob is written in."""
        return "experimental" if self.experimental else "method"

    @property
    def type(self) -> type:
        """int, float or str (an ``auto`` knob: float, though its value may be "auto")."""
        return float if self.auto else type(self.default)

    @property
    def cli_type(self) -> type:
        """The type click converts the option to (an ``auto`` knob's text: see cli_value)."""
        return str if self.auto else self.type

    def cli_value(self, value):
        """An ``auto`` knob's option text as "auto" or a float (other text is left for check
        to refuse); other knobs' values unchanged."""
        if self.auto and isinstance(value, str) and value != "auto":
            try:
                return float(value)
            except ValueError:
                return value
        return value

    @property
    def option(self) -> str:
        """The command-line option, ``--max-iterations`` for ``max_iterations``."""
        return "--" + self.name.replace("_", "-")

    def check(self, value, src: str, name: str | None = None):
        """``value`` validated (as int, float or str), or a one-line PopvolError naming
        ``name`` (default: ``table.name``)."""
        name = name or f"{self.table}.{self.name}"
        if self.auto:
            if isinstance(value, str) and value == "auto":
                return "auto"
            lo, hi = self.allowed
            try:
                return check.number(value, name, src, lo, hi)
            except PopvolError:
                raise PopvolError(f"{src}: {name} = {check._show(value)} must be 'auto' or a finite "
                                  f"number in [{check._fmt(lo)}, {check._fmt(hi)}]") from None
        if self.type is str:
            return check.choice(value, name, src, self.allowed)
        lo, hi = self.allowed
        if self.type is int:
            if self.zero and _is_zero(value):
                return 0
            try:
                return check.integer(value, name, src, lo, hi)
            except PopvolError:
                if not self.zero:
                    raise
                raise PopvolError(f"{src}: {name} = {check._show(value)} must be 0 or an integer "
                                  f"in [{lo}, {hi}]") from None
        return check.number(value, name, src, lo, hi)


def _is_zero(value) -> bool:
    return check._is_int(value) and int(value) == 0


KNOBS: tuple[Knob, ...] = (
    Knob("resolution", 128, (2, 4096), "Cells along the longest side of each light's propagation domain.",
         cli=("render", "compare")),
    Knob("solver", "ordinates", ("ordinates", "sweep", "jacobi", "binned"),
         "Propagation solver of suns and environments' lights.",
         "Gauss-Seidel sweeps with one lobe per lattice direction, in which light keeps its direction "
         "until it scatters, so that light scattered sideways keeps going sideways, every order "
         "walked with no diffusion stage (needs `rule = \"moment\"`; docs/METHOD.md, \"Six "
         "ordinates\"); or one lobe per cell about the light's axis, with the diffusion stage of "
         "`isotropic`: Gauss-Seidel sweeps along the light (faster on small scenes, further from "
         "Mitsuba: docs/ACCURACY.md), the Jacobi wavefront (reference semantics: each iteration "
         "moves every packet one cell), or the Jacobi wavefront with each cell's light kept in 17 "
         "fixed anisotropy bins instead of one merged lobe (linear in the light, so the answer does "
         "not depend on the schedule; 5-40x slower). Point lights: see `point_walk`.",
         experimental=True),
    Knob("ordinates", 18, (6, 18), "Directions of `solver = \"ordinates\"`: 6 or 18.",
         "18: one lobe per face and per edge of the lattice, so that light scattered 45 degrees off "
         "its way goes on diagonally (docs/METHOD.md, \"Eighteen ordinates\"). 6: one per face "
         "(+-d, +-u, +-v), light scattered 45-135 degrees goes exactly sideways: about half the "
         "time to walk, further from Mitsuba on sunlit clouds (docs/ACCURACY.md). The other "
         "solvers ignore it.", experimental=True, allowed_text="6 or 18"),
    Knob("point_walk", "auto", ("auto", "sweep", "ordinates"), "How a point light's scattered light is walked.",
         "`\"sweep\"`: sweeps of one lobe per cell in its spherical domain, with the diffusion stage "
         "of `isotropic`; `\"ordinates\"` (with `solver = \"ordinates\"`): its first scattering as "
         "the source of an ordinates walk on a box over the medium, every order walked, the box "
         "turned toward the medium as a sun's domain where the light is outside it (docs/METHOD.md, "
         "\"A point light's ordinates\"); `\"auto\"`: the ordinates for a light outside the "
         "medium's box (its spherical domain a cone), the sweeps for one inside or near it, where "
         "the box's lattice cannot be aligned with its light.", experimental=True),
    Knob("rule", "moment", ("moment", "paper"), "Anisotropy of each outgoing part.",
         "The mean cosine of its slice of the lobe (conserves the first moment) or the cell's own "
         "(the paper's rule, with a one-lobe `solver` only).", experimental=True),
    Knob("decay", "poisson", ("poisson", "paper"), "Anisotropy decay over a step s.",
         "exp(-sigma_s s (1 - g)) or g^(sigma_s s) (supplement Eq. 12; needs g >= 0).",
         experimental=True),
    Knob("isotropic", "diffusion", ("diffusion", "walk"), "What happens to light whose lobe has spread.",
         "It is handed to a diffusion solve with the physical coefficient D = 1 / (3 sigma_tr) "
         "(`popvol/diffusion.py`), or it keeps walking cell by cell (the papers' POP); see the "
         "README on bias. For point lights and the one-lobe solvers: a sun or an environment's light "
         "walked with `solver = \"ordinates\"` (the default) always walks.", experimental=True),
    Knob("direct", "domain", ("domain", "voxels"), "Where a sun's unscattered light is computed.",
         "\"domain\": on the walk's own cells; \"voxels\": on a domain of its own whose cells are no "
         "wider than the medium's smallest voxel (at most 4 times `resolution`), Beer-Lambert through the "
         "true density, so that shadows and lit faces are as sharp as the voxels where the walk's cells "
         "are wider (docs/METHOD.md, \"Unscattered light\").", experimental=True),
    Knob("handover_scale", 2.0, (0.0, 100.0), "Hand-over threshold of the diffusion stage.",
         "With `isotropic = \"diffusion\"` (point lights, and suns with a one-lobe `solver`): a "
         "packet leaves the walk when its anisotropy "
         "\\|a\\| < handover_scale * (1 - exp(-sigma_tr h)), h the cell size, sigma_tr = sigma_a + "
         "sigma_s (1 - g): a threshold in the medium's transport mean free paths, so images do not "
         "change with the grid.", experimental=True),
    Knob("environment_handover_scale", 0.5, (0.0, 100.0),
         "`handover_scale` of the lights whose unscattered light is not kept apart.",
         "An environment's lights (and a sun with `a0` < 1) carry their single scattering in the "
         "walk's lobes, not in a direct field, so they stay in the walk longer: at a sun's threshold "
         "(2) the sky-lit WDAS cloud is x0.64 of Mitsuba's brightness, at 0.5 x0.79 "
         "(docs/METHOD.md, \"Hand-over\").", experimental=True),
    Knob("diffusion_resolution", 64, (0, 4096), "Cells along the longest side of the diffusion grid.",
         "Its cells are blocks of the light's domain; 0 = the domain's own cells."),
    Knob("environment_resolution", 64, (2, 4096), "`resolution` of the domains of an environment's lights.",
         "Soft light needs fewer cells; 0 = `resolution`.", zero=True),
    Knob("tolerance", 3e-3, (1e-12, 1.0), "Stop when the energy in flight is below tolerance * injected.",
         "What is then pending in the diffusion region is handed over; the diffusion solve stops at a "
         "residual of 0.1 tolerance."),
    Knob("tail", 0.2, (0.0, 1.0), "Light in flight at which the eighteen-ordinate walk moves to wider cells.",
         "A sun's or an environment's eighteen-ordinate walk sends only its brighter packets on its own "
         "cells, stops there once at most this share of the injected light is in flight after two sweeps "
         "or more (one each way along the light), and walks what it then holds to the tolerance on blocks "
         "of 2^3 cells; 0 = all of it on its own cells. Images move under 1.5 % at 128 cells, under 1 % at "
         "256 and up to 3.1 % at 64 (docs/METHOD.md, \"The walk's tail on wider cells\")."),
    Knob("max_iterations", 0, (0, 10_000_000), "Cap on iterations; 0 = automatic.",
         "A capped run is reported as not converged in `--stats`.",
         default_text="0 (automatic: 400 sweeps, or 40 x the domain's perimeter for Jacobi)"),
    Knob("step", 1.0, (1e-3, 16.0), "Ray-marching step, in voxels of the medium."),
    Knob("max_step", 2, (1, 64), "Most steps one ray-marching sample spans where the medium is thin.",
         "In a block of 8^3 voxels whose densest voxel makes n steps together at most half a mean "
         "free path thick, one sample spans up to n steps (never past the block, nor longer than "
         "1/8 of the distance to a point light); 1 = one sample per step. Larger is faster where "
         "the medium is thin and noisier there (docs/METHOD.md, \"Rendering\", Eq. 25c)."),
    Knob("gather", 64, (0, 4096), "Directions of the gathered last scattering (0: off).",
         "The renderer gathers the light reaching each voxel from N directions (half of them in a "
         "cap about the view), transported through the medium from the fields' in-scattered light, "
         "and scatters it toward the camera with the phase function, instead of lighting the voxel "
         "from the fields' lobes; only the single scattering is lit per sample (docs/METHOD.md, "
         "\"Gathered last bounce\"). 0 lights every sample from the lobes: faster, and "
         "1.1-4.9x further from Mitsuba at 128 cells (docs/ACCURACY.md).", cli=("render", "compare")),
    Knob("gather_resolution", 64, (0, 4096), "Blocks along the longest side of the gather's grid.",
         "The light is gathered on blocks of f^3 voxels of the medium, the fewest with at most this "
         "many blocks along the grid's longest side but none wider than half a mean free path where "
         "the medium is dense, and read back by trilinear interpolation (the sweeps cost about "
         "f^-3 as much); 0 = the medium's own voxels."),
    Knob("voxel_depth", 0.0, (0.0, 1000.0), "Thickest voxel, in mean free paths, that light is solved and rendered on.",
         "0 = the medium's own voxels. Otherwise each voxel side is cut into the smallest odd "
         "number of equal parts at least sigma_t,max h / voxel_depth (at most 3; sigma_t,max of "
         "the densest voxel; odd, so that the finer grid keeps the medium's trilinear density "
         "exactly) and the density is read trilinearly at the finer voxels' centres, so that the "
         "single scattering and the gathered last bounce resolve the lit skin of media whose voxels "
         "are about a mean free path thick or more (docs/METHOD.md, \"Voxels thinner than a mean "
         "free path\"). It costs up to 27 times the voxels, and the render about as much more.",
         cli=("render", "compare")),
    Knob("spp", 1, (1, 4096), "Camera rays per pixel.",
         "1 = one ray through the pixel centre, lit at the march segments' midpoints; more = "
         "that many rays at hashed (seeded) sub-pixel and along-ray offsets.", cli=("render", "compare")),
    Knob("exposure", "auto", (-64.0, 64.0), "PNG exposure in stops, or \"auto\".",
         "\"auto\" places the 99th percentile of the lit pixels' luminance at 1.44 (Zone VIII: "
         "white with texture), shown at sRGB code 197 by `tone = \"aces\"`. The EXR stays linear.",
         auto=True, cli=("render",)),
    Knob("tone", "aces", ("aces", "clip"), "Tone curve of the PNG.",
         "The ACES 2.0 SDR sRGB view (OpenColorIO's built-in config; highlights roll off) or "
         "clip to [0, 1] and sRGB-encode. The EXR stays linear.", cli=("render",)),
    Knob("seed", 0, (0, 2**63 - 1), "Seed of the pixel jitter (spp > 1).", allowed_text="[0, 2^63 - 1]"),
)

#: Knobs by name.
KNOB: dict[str, Knob] = {k.name: k for k in KNOBS}


class _MethodBase:
    """Behaviour of :class:`Method` (its fields come from :data:`KNOBS`)."""

    def validate(self, src: str):
        """Check every field (a one-line PopvolError naming ``src`` and the field) and store
        it as int, float or str. Returns self."""
        for k in KNOBS:
            setattr(self, k.name, k.check(getattr(self, k.name), src))
        if self.ordinates not in (6, 18):
            raise PopvolError(f"{src}: experimental.ordinates = {self.ordinates} must be 6 or 18")
        if self.point_walk == "ordinates" and self.solver != "ordinates":
            raise PopvolError(f"{src}: experimental.point_walk = 'ordinates' needs experimental.solver = "
                              f"'ordinates' (the default), not {self.solver!r}")
        if self.solver == "ordinates" and self.rule != "moment":
            raise PopvolError(f"{src}: experimental.rule = {self.rule!r} needs experimental.solver = 'sweep', "
                              "'jacobi' or 'binned' (the default, 'ordinates', takes rule = 'moment' only: its "
                              "side parts carry their own slice's mean cosine)")
        return self

    def experimental_changes(self) -> dict:
        """The experimental knobs that differ from their default, as {name: value}."""
        return {k.name: getattr(self, k.name) for k in KNOBS
                if k.experimental and getattr(self, k.name) != k.default}


def _method_doc() -> str:
    lines = ["How the light is propagated and the image rendered (docs/SCENE.md, ``[method]`` and",
             "``[experimental]``). One field per knob of :data:`popvol.method.KNOBS`:", ""]
    for k in KNOBS:
        tag = " (experimental)" if k.experimental else ""
        lines.append(f"{k.name}{tag}: {k.help} Default {k.default!r}.")
    return "\n".join(lines)


Method = make_dataclass(
    "Method", [(k.name, k.type, field(default=k.default)) for k in KNOBS], bases=(_MethodBase,),
    namespace={"__module__": __name__, "__doc__": _method_doc()})


#: id(method) -> the names of its knobs that the command line set (:func:`mark_overridden`); kept
#: apart from the Method, whose vars() are its knobs (its key, its digest, the stats' JSON)
_OVERRIDDEN: dict[int, frozenset] = {}


def mark_overridden(method, names) -> None:
    """Remember that the command line set knobs ``names`` of ``method`` (for :func:`knob_field`),
    for as long as that Method object lives."""
    key = id(method)
    if key not in _OVERRIDDEN:
        weakref.finalize(method, _OVERRIDDEN.pop, key, None)
    _OVERRIDDEN[key] = _OVERRIDDEN.get(key, frozenset()) | frozenset(names)


def knob_field(method, name: str, source: str) -> str:
    """How a message names knob ``name`` of ``method`` and its value: ``--resolution = 4096 (on
    the command line)`` where the command line set it (:func:`mark_overridden`, by
    popvol.scene.apply_overrides), else ``SOURCE: method.resolution = 4096`` (``experimental.``
    for an experimental knob)."""
    k = KNOB[name]
    value = getattr(method, name)
    if name in _OVERRIDDEN.get(id(method), ()):
        return f"{k.option} = {value} (on the command line)"
    return f"{source}: {k.table}.{name} = {value}"


def method_from_tables(method_table, experimental_table, src: str) -> "Method":
    """A validated Method from a scene's ``[method]`` and ``[experimental]`` tables (dicts)."""
    given = {}
    for table_name, tbl, experimental in (("method", method_table, False),
                                          ("experimental", experimental_table, True)):
        tbl = check.table(tbl, table_name, src)
        if "handover" in tbl:
            raise PopvolError(f"{src}: {table_name}.handover (a fixed |a| threshold) was replaced by "
                              "experimental.handover_scale (the threshold per cell is handover_scale * "
                              "(1 - exp(-sigma_tr s)), default 2; see docs/SCENE.md): remove the key or rename it")
        for key in tbl:
            k = KNOB.get(key)
            if k is not None and k.experimental != experimental:
                what = ("an experimental knob: move it to an [experimental] table" if k.experimental
                        else "not an experimental knob: move it to the [method] table")
                raise PopvolError(f"{src}: {table_name}.{key} is {what}")
        check.known_keys(tbl, [k.name for k in KNOBS if k.experimental == experimental], f"{table_name}.", src)
        given.update(tbl)
    return Method(**given).validate(src)


def method_tables(method) -> dict:
    """The scene-file tables of ``method``: {"method": every non-experimental knob,
    "experimental": the experimental knobs that differ from their default (often empty)}.
    Values are plain int, float and str (TOML-writable)."""
    plain = {int: int, float: float, str: str}
    out = {"method": {}, "experimental": {}}
    for k in KNOBS:
        v = getattr(method, k.name)
        v = v if k.auto and isinstance(v, str) else plain[k.type](v)
        if not k.experimental:
            out["method"][k.name] = v
        elif v != k.default:
            out["experimental"][k.name] = v
    return out


def cli_knobs(command: str) -> list[Knob]:
    """The knobs offered as ``--name`` options by ``popvol COMMAND``."""
    return [k for k in KNOBS if command in k.cli]


def knob_table_markdown(experimental: bool = False) -> str:
    """The docs/SCENE.md table of the ``[method]`` (or ``[experimental]``) knobs."""
    rows = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for k in KNOBS:
        if k.experimental != experimental:
            continue
        kind = {int: "integer", float: "number", str: "string"}[k.type]
        if k.auto:
            kind = 'number or `"auto"`'
            default = f'`"{k.default}"`'
            allowed = f'`"auto"`, [{check._fmt(k.allowed[0])}, {check._fmt(k.allowed[1])}]'
        elif k.type is str:
            default = f'`"{k.default}"`'
            allowed = ", ".join(f'`"{a}"`' for a in k.allowed)
        else:
            default = k.default_text or check._fmt(k.default)
            lo, hi = k.allowed
            allowed = k.allowed_text or f"{'0 or ' if k.zero else ''}[{check._fmt(lo)}, {check._fmt(hi)}]"
        meaning = " ".join(s for s in (k.help, k.doc) if s)
        rows.append(f"| `{k.name}` | {kind} | {default} | {allowed} | {meaning} |")
    return "\n".join(rows)


__all__ = ["Knob", "KNOBS", "KNOB", "Method", "method_from_tables", "method_tables", "cli_knobs",
           "knob_table_markdown"]
