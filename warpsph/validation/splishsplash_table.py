"""The table of docs/splishsplash.md: every scene pysplishsplash ships, run through warpsph's importer (which
scene files load, run or are refused, and why).

    pip download pysplishsplash==2.19.0 --no-deps -d /tmp/pss && unzip -q /tmp/pss/*.whl -d /tmp/pss/x
    python -m warpsph.validation.splishsplash_table /tmp/pss/x/pysplishsplash-2.19.0.data/data/bin/data/Scenes > table.md

Per scene: runs (loads, and its particles and bodies sample, at scale 1; with --steps N also N time
steps on the CPU at --scale) or refused (the reason), warpsph's fluid particle count beside
SPlisHSPlasH's (its createFluidBlocks rule; "?" where fluid comes from particle files), and the
keys mapped and refused. The scene files are read in place: nothing of pysplishsplash is copied.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from warpsph import SceneError, load_scene
from warpsph.io.splishsplash import conversion_of, translate
from warpsph.simulation import Simulation, count_particles, sample_scene


def short(item):
    """'Materials[0].Standard viscosity.viscosity -> fluid.viscosity = 0.01' -> its key."""
    return item.split(" -> ")[0].split(": ")[0]


def grouped(keys):
    """Keys sharing a prefix written once: Configuration.DFSPH.{maxError, maxIterations}."""
    groups = {}
    for key in keys:
        head, _, tail = key.rpartition(".") if "." in key and " " not in key.rpartition(".")[2] else ("", "", key)
        groups.setdefault(head, []).append(tail)
    out = []
    for head, tails in groups.items():
        if not head:
            out += tails
        elif len(tails) == 1:
            out.append(f"{head}.{tails[0]}")
        else:
            out.append(f"{head}.{{{', '.join(tails)}}}")
    return ", ".join(out) or "–"


def row(path, steps, scale):
    data = json.loads(Path(path).read_text(encoding="utf-8-sig"))
    c = translate(data, path)
    status, count = "runs", "–"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            scene = load_scene(path)
            count = str(count_particles(scene)[0])
            sample_scene(scene)
            if steps:
                sim = Simulation(load_scene(path, scale=scale), device="cpu")
                for _ in range(steps):
                    sim.step()
        except SceneError as exc:
            text = str(exc).split(": ", 2)[-1] if not c.errors and not c.refused else ""
            if c.errors:
                status = "refused: " + "; ".join(e.split(": ", 2)[1] for e in c.errors)
            elif c.refused:
                status = "refused: " + "; ".join(sorted({short(r) for r in c.refused}))
            else:
                status = "refused: " + text.replace("\n", " ")
        conv = conversion_of(path) or c
    theirs = "?" if c.splishsplash_particles is None else str(c.splishsplash_particles)
    if count == "–" and not c.errors and conv.scene.get("fluid_blocks") is not None:
        count = "–"
    mapped = sorted({short(m) for m in conv.mapped if "(SPlisHSPlasH's default)" not in m})
    refused = [short(r) for r in conv.refused]
    return f"| {Path(path).stem} | {status} | {count} | {theirs} | {grouped(mapped)} | {grouped(refused)} |"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", help="pysplishsplash's data/Scenes folder")
    parser.add_argument("--steps", type=int, default=0, help="also run this many steps on the CPU")
    parser.add_argument("--scale", type=float, default=0.05, help="particle-count scale of those steps")
    args = parser.parse_args(argv)
    files = sorted(Path(args.scenes).glob("*.json"))
    print("| scene | warpsph | particles (warpsph) | particles (SPlisHSPlasH) | keys mapped | keys refused |")
    print("|---|---|---|---|---|---|")
    for path in files:
        print(row(path, args.steps, args.scale).replace(str(Path(args.scenes)), "Scenes"), flush=True)


if __name__ == "__main__":
    sys.exit(main())
