"""Every render parameter, declared once with its default and help text.

The CLI flags (``igi render``/``igi serve``), the docs table and the viewer's parameter panel
are all generated from :data:`PARAMS`; nothing else declares a default.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields, make_dataclass, replace
from typing import Any


@dataclass(frozen=True)
class Param:
    name: str
    type: type
    default: Any
    help: str
    group: str = "render"
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None
    viewer: bool = True  # shown as a control in the browser panel
    special: str | None = None  # what the value -1 means ("auto", "unlimited", ...), if it is a sentinel
    scale: str = "linear"  # the viewer slider's scale: "linear" or "log" (ranges spanning decades)

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")


PHOTON_BOOST_MAX = 16  # photon_share: a set takes at most this many times --photons

PARAMS: tuple[Param, ...] = (
    # Instant radiosity (paper §4, §5.1)
    Param("direct_vpls", int, 4, "VPLs placed on the emitters per set (direct light)", "vpl", 0, 256),
    Param("indirect_vpls", int, 30,
          "VPLs at the vertices of light walks per set (indirect light) on the frames of a still "
          "camera (30 against 18: 10% less error at equal time over six shared scenes, geometric "
          "mean of 5 seeds; 13-31% less on the rooms lit indirectly, 5-11% more on the two whose "
          "error is mostly caustics or many lamps' direct light)", "vpl", 0, 1024),
    Param("moving_indirect_vpls", int, 18,
          "at most this many indirect VPLs per set on the frames of a moving camera (a streamed view's "
          "frame after each move): such a frame is shown once, so frame rate counts there, not error at "
          "equal time; -1: as --indirect-vpls", "vpl", -1, 1024),
    Param("light_path_length", int, 4, "maximum light-walk length for VPLs (paper: 4)", "vpl", 1, 64),
    Param("clamp", float, -1.0,
          "minimum squared VPL distance as a fraction of the squared scene diagonal (-1: scene default 1e-3)",
          "vpl", -1.0, 1.0),
    Param("clamp_first", float, 0.01,
          "with consistent accumulation, the first frame's squared clamp distance as a fraction of the "
          "squared scene diagonal; frame i clamps at the larger of clamp and clamp_first/(i+1), the "
          "clamped light given back by the compensation (a wide clamp takes the first frames' VPL "
          "spikes); 0: the plain clamp from the first frame", "vpl", 0.0, 1.0),
    Param("vpl_importance", int, -1,
          "indirect VPLs kept by their contribution to the view (Georgiev & Slusallek 2010): "
          "-1 auto (when a pilot set's contributions are uneven), 0 off, 1 on", "vpl", -1, 1),
    Param("vpl_oversample", int, 8, "candidate light walks per kept walk when VPLs are importance-sampled",
          "vpl", 1, 64),
    Param("vpl_portals", bool, True,
          "with VPLs importance-sampled in a sky-lit scene, half the light walks from the sky start "
          "where the view's escaped rays show it entering (openings found from the view; the other "
          "half on the disk around the scene, so the estimate stays unbiased)", "vpl"),
    Param("vpl_lobe_alpha", float, 0.5,
          "glossy VPLs smoother than this roughness radiate through their lobe widened to it (path "
          "regularization, Kaplanyan & Dachsbacher 2013; at 0.5 a GGX peak is within ~4x a Lambertian "
          "VPL's, so no spikes where a smooth floor's VPL faces a wall); shrinks like the photon "
          "radius while accumulating consistently; 0: off",
          "vpl", 0.0, 1.0),
    Param("shadow_roulette", float, 1.0,
          "Russian roulette on shadow rays: an (end point, VPL) pair (a glossy end point's light "
          "guessed by its lobe's shape) whose unshadowed light is below this fraction of the end "
          "point's mean pair traces its ray with probability light/(fraction x mean) and counts 1/p "
          "(unbiased; skips the rays of pairs that carry little light; 1 gave 2-4% less error at equal "
          "time than 0.5 on six shared scenes); 0: every pair traces", "vpl", 0.0, 1.0),
    Param("lobe_light_samples", int, 4,
          "emitter samples per set that a split glossy lobe takes for its direct light (MIS with the "
          "lobe's sampled ray; the first of the set's, reweighted): the lobe's direct light costs "
          "this many shadow rays, not the set's every sample; 0: all", "vpl", 0, 256),
    Param("light_samples", int, 0,
          "emitters sampled per set in many-light scenes (0: all emitters share the direct VPLs by power)",
          "vpl", 0, 1024),
    # Caustics (paper §4.1)
    Param("photons", int, 500, "caustic photons per light per set (paper: 500-1500); lights of unequal power "
          "share this many times their effective number in proportion to power", "caustics", 0, 100000),
    Param("photon_share", float, 0.1,
          "photons grow with the caustics' share of the light: where more than this share of the lights' flux "
          "ends in caustic photons (a pilot set), a set takes (share/this)^2 times --photons in steps of "
          f"sqrt(2), at most {PHOTON_BOOST_MAX:g}x (cornell-box-water, 0.37: 16x, 4-5x less error at equal "
          "time; scenes at most this share keep --photons; a moving view's frames keep it too); 0: always "
          "--photons", "caustics", 0.0, 1.0),
    Param("photon_radius", float, -1.0,
          "caustic gather radius as a fraction of the scene diagonal (-1: scene default 0.005)",
          "caustics", -1.0, 1.0),
    # Interleaved sampling + discontinuity buffer (paper §4.2, §4.3)
    Param("interleave", int, 5,
          "interleave pattern n (n x n sets of VPLs/photons; 1 = one set). 5 (the paper's Fig. 3): "
          "25 distinct VPL sets per frame for the same shadow rays per pixel as 3, 1.5-2.5x lower "
          "error at equal time on the shared scenes",
          "filter", 1, 8),
    Param("filter_window", int, -1, "discontinuity-buffer window (-1: interleave size, 1: off)", "filter", -1, 15),
    Param("depth_threshold", float, 0.05, "relative depth difference that breaks the filter", "filter", 0.0, 1.0),
    Param("normal_threshold", float, 0.9, "minimum normal dot product inside the filter", "filter", -1.0, 1.0),
    Param("filter_glossy_alpha", float, 0.3,
          "glossy surfaces at least this rough are filtered like irradiance; smoother ones are split at "
          "the first hit: diffuse layer filtered, glossy lobe traced by one sampled ray (a smooth plastic's "
          "coat by its mirror ray; 0: nothing split)",
          "filter", 0.0, 10.0),
    Param("filter_lobe_alpha", float, 0.04,
          "a split plastic's glossy lobe at least this rough is filtered: the discontinuity buffer "
          "averages the lobe's one sampled ray with those of its neighbours that have one, beside the "
          "irradiance, and adds the result, so its light samples (shared by an interleave set) do not "
          "print as dots of the set's lights; smoother lobes (mirror-like reflections) stay unfiltered",
          "filter", 0.0, 10.0),
    # Eye paths
    Param("max_depth", int, -1, "path segments as in Mitsuba (-1 unlimited, 2 = direct only)", "path", -1, 64),
    Param("specular_depth", int, 8, "longest mirror/glass chain followed from the eye", "path", 1, 64),
    # Accumulation
    Param("accumulate", bool, True, "average frames while nothing moves", "accumulate", viewer=True),
    Param("consistent", bool, True,
          "while accumulating, remove the biases frames cannot average away: Russian-roulette light "
          "walks, shrinking photon radius, fading image filter", "accumulate"),
    Param("consistent_first_frame", bool, True,
          "the first frame after a reset already takes the consistent estimators (Russian-roulette "
          "walks, clamp compensation): ~20% more time for a first frame without their bias; a "
          "streamed view skips them on the frames of a moving camera", "accumulate", viewer=False),
    Param("moving_camera", bool, False,
          "this frame is a streamed view's first after a camera move (set by the stream, not by hand): "
          "it is shown once, so it takes at most moving_indirect_vpls indirect VPLs a set",
          "accumulate", viewer=False),
    Param("ppm_alpha", float, 2 / 3, "photon radius shrink per accumulated frame: r²ᵢ₊₁ = r²ᵢ(i+α)/(i+1)",
          "accumulate", 0.05, 1.0),
    Param("filter_frames", int, 32,
          "accumulated frames after which the discontinuity buffer is faded out (-1: always filter); "
          "with --filter-guide the irradiance does not fade (the guided filter's blur shrinks with the "
          "noise), nor, with --filter-select, the split lobes (the running mean takes back their "
          "measured bias)",
          "accumulate", -1, 100000),
    Param("filter_guide", float, 2.0,
          "edge stopping from the frames accumulated so far: a neighbour's irradiance is averaged only "
          "while the earlier frames' means of it and of the pixel differ by at most this many standard "
          "errors, so the discontinuity buffer stops blurring shadow edges as the frames learn them "
          "(0: off)", "accumulate", 0.0, 100.0),
    Param("filter_select", float, 1.5,
          "with --filter-guide, each pixel of the running mean keeps the discontinuity buffer's share only "
          "as far as that share's bias, estimated from the frames (the mean of filtered minus raw radiance "
          "squared, less this many times its variance (more over the first frames), over the filter's "
          "window), is small beside the noise the filter removes; where it is not, the pixel leans to its "
          "raw mean (0: off)",
          "accumulate", 0.0, 100.0),
    Param("seed", int, 0, "seed of the first frame's Sobol scrambling", "accumulate", 0, 2**31 - 1, viewer=False),
)

# How the viewer presents a parameter: the meaning of its -1 sentinel, and a log slider where
# the range spans decades.
_PRESENTATION = {
    "direct_vpls": (None, "log"), "indirect_vpls": (None, "log"),
    "moving_indirect_vpls": ("as still", "log"), "light_path_length": (None, "log"),
    "clamp": ("auto", "log"), "light_samples": (None, "log"), "photons": (None, "log"),
    "photon_radius": ("auto", "log"), "filter_window": ("auto", "linear"), "max_depth": ("unlimited", "log"),
    "specular_depth": (None, "log"), "filter_frames": ("always", "log"),
}
PARAMS = tuple(replace(p, special=_PRESENTATION[p.name][0], scale=_PRESENTATION[p.name][1])
               if p.name in _PRESENTATION else p for p in PARAMS)

PARAM_BY_NAME = {p.name: p for p in PARAMS}


def boosted_photon_bound(photons: int) -> int:
    """The most photons per light per set --photon-share may give for ``photons``: PHOTON_BOOST_MAX
    times as many, within the parameter's own bound (worker.caustics.boosted_photons, the memory
    check of common.limits)."""
    return int(min(photons * PHOTON_BOOST_MAX, PARAM_BY_NAME["photons"].max))

Params = make_dataclass(
    "Params",
    [(p.name, p.type, field(default=p.default)) for p in PARAMS],
    frozen=True,
)
Params.__doc__ = "Render parameters; build with Params(**overrides). Fields and defaults come from PARAMS."


def make_params(**overrides: Any) -> "Params":
    """Params with overrides, each checked against its declaration."""
    for name, value in overrides.items():
        if name not in PARAM_BY_NAME:
            raise ValueError(f"unknown parameter {name!r}")
        p = PARAM_BY_NAME[name]
        if p.type is bool:
            overrides[name] = bool(value)
            continue
        try:
            v = p.type(value)
        except (TypeError, ValueError):
            raise ValueError(f"parameter {name}: {value!r} is not a {p.type.__name__}") from None
        if v != v:  # NaN
            raise ValueError(f"parameter {name}: NaN")
        if p.min is not None and v < p.min or p.max is not None and v > p.max:
            raise ValueError(f"parameter {name}={v} outside [{p.min}, {p.max}]")
        overrides[name] = v
    return Params(**overrides)


def params_to_dict(params: "Params") -> dict:
    return {f.name: getattr(params, f.name) for f in fields(params)}


def _argparse_text(text: str) -> str:
    """Help text as argparse wants it: a literal % doubled (it formats help with %)."""
    return text.replace("%", "%%")


def add_arguments(parser: argparse.ArgumentParser, exclude: tuple[str, ...] = ()) -> None:
    """Add one flag per declared parameter (defaults left to the declaration)."""
    group = parser.add_argument_group("render parameters")
    for p in PARAMS:
        if p.name in exclude:
            continue
        if p.type is bool:
            group.add_argument(p.flag, dest=p.name, action=argparse.BooleanOptionalAction,
                               default=None, help=_argparse_text(f"{p.help} (default: {p.default})"))
        else:
            group.add_argument(p.flag, dest=p.name, type=p.type, default=None,
                               help=_argparse_text(f"{p.help} (default: {p.default})"))


def params_from_args(args: argparse.Namespace) -> "Params":
    overrides = {p.name: getattr(args, p.name) for p in PARAMS
                 if getattr(args, p.name, None) is not None}
    return make_params(**overrides)


def markdown_table() -> str:
    """The docs table of parameters (docs/parameters.md is generated from this)."""
    rows = ["| flag | default | range | meaning |", "|---|---|---|---|"]
    for p in PARAMS:
        rng = "" if p.min is None else f"{p.min} … {p.max}"
        rows.append(f"| `{p.flag}` | {p.default} | {rng} | {p.help} |")
    return "\n".join(rows)


def parameters_doc() -> str:
    """docs/parameters.md, generated: `python -c "import igi.common.params as p; print(p.parameters_doc())" > docs/parameters.md`."""
    return ("# Render parameters\n\nGenerated from `common/params.py` (the one declaration the CLI flags, "
            "this page and the viewer's panel come from). Every flag works with `igi render` and "
            "`igi serve`.\n\n" + markdown_table() + "\n")


# What an "auto" (-1) value resolves to where the renderer resolves it (worker/renderer.py
# DEFAULT_CLAMP, worker/caustics.py default_radius, master/discontinuity_buffer.py resolve_window).
AUTO_CLAMP = 1e-3
AUTO_PHOTON_RADIUS = 0.005


def values_in_use(values: dict) -> dict:
    """For each parameter at its -1 sentinel: the value the renderer uses instead (a number, or
    a word such as "unlimited"); the viewer shows it as "auto (= …)"."""
    out = {}
    for name, v in (values or {}).items():
        p = PARAM_BY_NAME.get(name)
        if p is None or p.special is None or v is None or v != -1:
            continue
        if name == "clamp":
            out[name] = AUTO_CLAMP
        elif name == "photon_radius":
            out[name] = AUTO_PHOTON_RADIUS
        elif name == "filter_window":
            out[name] = int(values.get("interleave", PARAM_BY_NAME["interleave"].default))
        elif name == "moving_indirect_vpls":
            out[name] = int(values.get("indirect_vpls", PARAM_BY_NAME["indirect_vpls"].default))
        else:
            out[name] = p.special
    return out


def viewer_schema() -> list[dict]:
    """Declarations the browser panel builds its controls from."""
    return [
        {"name": p.name, "type": p.type.__name__, "default": p.default, "help": p.help,
         "group": p.group, "min": p.min, "max": p.max, "special": p.special, "scale": p.scale}
        for p in PARAMS if p.viewer
    ]
