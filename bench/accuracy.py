"""`igi bench accuracy`: relMSE against the Mitsuba references as frames accumulate, with wall time.

One run per (scene, variant): the image is rendered in-process (``render_local``, the same
tasks and filter as the cluster) at ``scale`` of the film size and compared, after each
checkpoint frame count, with the reference block-averaged by 1/scale (a box-filtered pixel of
the smaller image integrates exactly that block). Variants: ``paper`` (consistent
accumulation off: fixed clamp, fixed walk length, fixed photon radius, filter always on) and
``consistent`` (the defaults). A caustic mask restricts the error to pixels where the full
reference is much brighter than the direct-only one on surfaces lit through glass (see
:func:`caustic_mask`).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from igi.common.image_io import read_image, write_png
from igi.common.loader import load_scene
from igi.common.metrics import block_average, relmse

from .paths import SHARED
from .report import machine_info, md_table

VARIANTS = {"paper": {"consistent": False}, "consistent": {}}


def caustic_mask(name: str, block: int) -> np.ndarray | None:
    """Pixels whose light is mostly caustic: full GI exceeds 3x the direct-only reference and
    the pixel is not an emitter (both references agree there). Derived from the references only."""
    full = SHARED / "references" / f"{name}.exr"
    direct = SHARED / "references" / f"{name}-direct.exr"
    if not (full.exists() and direct.exists()):
        return None
    f = block_average(read_image(full), block).mean(axis=-1)
    d = block_average(read_image(direct), block).mean(axis=-1)
    mask = (f > 3 * d + 0.05) & (f > 0.2) & (np.abs(f - d) / np.maximum(f, 1e-6) > 0.01)
    return mask


def measure(scenes: list[str], frames: list[int], scale: float = 0.5, variants: list[str] | None = None,
        out: str | None = None, images: str | None = None, **overrides) -> dict:
    from igi.master.inprocess import render_local
    from igi.worker.renderer import Renderer

    block = int(round(1 / scale))
    variants = variants or list(VARIANTS)
    results = []
    for name in scenes:
        path = SHARED / "scenes" / name / "scene.xml"
        ref = block_average(read_image(SHARED / "references" / f"{name}.exr"), block)
        h, w = ref.shape[:2]
        mask = caustic_mask(name, block)
        t_load = time.perf_counter()
        scene = load_scene(path)
        renderer = Renderer(scene)
        load_s = time.perf_counter() - t_load
        for variant in variants:
            params = dict(VARIANTS[variant], **overrides)
            rows = []
            t0 = time.perf_counter()
            last = {}

            def on_frame(i, img, rows=rows, t0=t0, last=last):
                n = i + 1
                if n in frames:
                    row = {"frames": n, "seconds": time.perf_counter() - t0, "relmse": relmse(img, ref)}
                    if mask is not None and mask.any():
                        m = mask[..., None].repeat(3, axis=-1)
                        row["relmse_caustic"] = float(np.mean(((img - ref) ** 2 / (ref ** 2 + 0.01))[m]))
                    rows.append(row)
                    last["img"] = img

            render_local(scene, params, max(frames), width=w, height=h, renderer=renderer,
                         on_frame=on_frame)
            if images and "img" in last:
                Path(images).mkdir(parents=True, exist_ok=True)
                write_png(Path(images) / f"{name}-{variant}-{max(frames)}.png", last["img"])
            results.append({"scene": name, "variant": variant, "params": params, "rows": rows,
                            "load_and_build_seconds": load_s, "size": [w, h],
                            "caustic_pixels": int(mask.sum()) if mask is not None else 0})
            if out:  # after every run, so a long sweep that is stopped keeps what it measured
                Path(out).parent.mkdir(parents=True, exist_ok=True)
                Path(out).write_text(json.dumps({"benchmark": "accuracy", "machine": machine_info(),
                                                 "scale": scale, "reference_block": block,
                                                 "results": results}, indent=2))
    doc = {"benchmark": "accuracy", "machine": machine_info(), "scale": scale,
           "reference_block": block, "results": results}
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(doc, indent=2))
    return doc


def markdown(doc: dict) -> str:
    frames = sorted({r["frames"] for res in doc["results"] for r in res["rows"]})
    head = ["scene", "variant"] + [f"{f} fr relMSE (s)" for f in frames]
    rows = []
    for res in doc["results"]:
        cells = {r["frames"]: r for r in res["rows"]}
        rows.append([res["scene"], res["variant"]] + [
            f"{cells[f]['relmse']:.4f} ({cells[f]['seconds']:.0f})" if f in cells else "" for f in frames])
    lines = md_table(head, rows)
    if any("relmse_caustic" in r for res in doc["results"] for r in res["rows"]):
        rows = []
        for res in doc["results"]:
            cells = {r["frames"]: r for r in res["rows"] if "relmse_caustic" in r}
            if cells:
                rows.append([res["scene"], res["variant"]] + [
                    f"{cells[f]['relmse_caustic']:.4f}" if f in cells else "" for f in frames])
        lines += ["", "Caustic region only:", ""] + md_table([h.replace("relMSE (s)", "relMSE") for h in head], rows)
    return "\n".join(lines)


def unit_fraction(text: str) -> float:
    """``--scale``: 1/n of the film size for a whole n >= 1 (the reference is averaged over
    n × n blocks), else argparse's usage error naming the value."""
    import argparse

    try:
        scale = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    n = round(1 / scale) if 0 < scale <= 1 else 0
    if n < 1 or abs(n * scale - 1) > 1e-9:
        raise argparse.ArgumentTypeError(f"{text!r} is not 1/n of the film size for a whole n (1, 0.5, 0.25, …)")
    return scale


def add_arguments(p) -> None:
    p.add_argument("scenes", nargs="+", help="shared scene names (e.g. cornell-box veach-ajar)")
    p.add_argument("--frames", default="1,4,16,64", help="checkpoint frame counts")
    p.add_argument("--scale", type=unit_fraction, default=0.5, help="fraction of the film size (1/integer)")
    p.add_argument("--variants", default="paper,consistent", help="paper and/or consistent")
    p.add_argument("--out", default="artifacts/bench_accuracy.json", help="JSON output")
    p.add_argument("--images", default=None, help="folder for the final images (PNG)")


def run(args) -> int:
    doc = measure(args.scenes, [int(f) for f in args.frames.split(",")], args.scale,
                  args.variants.split(","), args.out, args.images)
    md = markdown(doc)
    Path(args.out).with_suffix(".md").write_text(md + "\n")
    print(md)
    return 0
