"""The result files that main keeps in tools/results/: the ones behind the user docs' numbers (docs/validation.md's
tables, the papers' latest tables). Each is there, is a measurement that names its device, Warp version and commit
(a commit of this repository, a Warp inside the version range warpsph requires), and every number the docs quote from
it is the number in the file, to the digits the docs show. At most 20 files stay in main; every other result file
is on the `results` branch (`git show results:tools/results/NAME`), and a file the user docs name must be in one or
the other.

A new result the user docs cite: add it to KEPT and to tools/results/.gitignore (which ignores what studies write
there otherwise), and its quoted numbers to the checks below."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "tools" / "results"
DOCS = ROOT / "docs"
MAX_FILES = 20  # tracked files in tools/results/, .gitignore included (issue 41)

KEPT = (
    # docs/validation.md: the results table, the cost-against-accuracy tables, the cases' paragraphs
    "validate_taylor-green_256_h100_37.json", "validate_taylor-green_h200.json",
    "validate_lamb-oseen_models_session20_h100.json", "validate_vortex-surface_h200_216628b.json",
    "validate_vortex-surface_models_h100.json", "validate_standing-wave_256_h200.json",
    "validate_vortices_session20_h100.json", "rest_32_session21_h100.json", "validate_tank-at-rest_h200.json",
    "validate_sinking-sphere_h200.json", "validate_dam-front_h100_37.json",
    # docs/validation.md, performance (and docs/method.md, docs/splishsplash.md)
    "bench_dam_break_1M_models_h100.json", "scaling_h200x4.json", "multi_gpu_h200x2.json",
    "scaling_mpi_h200x4.json",
    "vs_splishsplash_1M_h100.json",
    # docs/papers.md: the latest run of each table
    "vr_fig7_h200_37.json", "rankine_fig11_h200_37.json", "vr_table1_h100.json",
)

NUMBER = re.compile(r"(?<![\w.])[-−+]?\d[\d,]*(?:\.\d+)?(?!\w)")


def load(name):
    return json.loads((RESULTS / name).read_text())


def page(name):
    return (DOCS / name).read_text()


def git(*args):
    """The output of a git command in this checkout, or None where there is no git or no repository."""
    if shutil.which("git") is None:
        return None
    done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return done.stdout if done.returncode == 0 else None


IN_GIT = git("rev-parse", "--is-inside-work-tree") is not None


def numbers(text):
    """The numbers written in a piece of markdown, as the text of each (unicode minus, thousands commas)."""
    return [m.group().replace("−", "-").replace(",", "") for m in NUMBER.finditer(text.replace("**", ""))]


def agrees(shown, value):
    """Whether the number as the docs write it (a string) is the value rounded to the digits shown."""
    if isinstance(value, bool):
        return shown == value
    decimals = len(shown.split(".")[1]) if "." in shown else 0
    return abs(float(shown) - value) <= 0.5 * 10 ** -decimals * (1 + 1e-9) + 1e-12


def table_after(text, marker):
    """The rows (lists of cells, the header and the rule skipped) of the first markdown table after ``marker``."""
    start = text.index(marker)
    lines = text[start:].splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    rows = []
    for line in lines[first + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip().strip("|"))])
    assert rows, marker
    return rows


def check_table(text, marker, rows, columns, where):
    """Each row of the table after ``marker``: its label (the first cell, or its first number) names a dict in
    ``rows``; each later cell's numbers are the values of that dict's keys in ``columns`` (None: not checked;
    yes / no: a bool)."""
    table = table_after(text, marker)
    for cells in table:
        label = cells[0].replace("**", "")
        values = rows.get(label)
        if values is None:
            values = rows[numbers(label)[0]]
        for cell, keys in zip(cells[1:], columns):
            if keys is None or cell in ("—", "-"):
                continue
            if cell.replace("**", "") in ("yes", "no"):
                assert values[keys[0]] is (cell.replace("**", "") == "yes"), (where, label, cell)
                continue
            shown = numbers(cell)
            assert shown, (where, label, cell, keys)
            for number, key in zip(shown, keys):
                assert agrees(number, values[key]), \
                    f"{where}: {label}, {key}: the docs say {number}, the file {values[key]}"
    return table


def by_resolution(name, **derived):
    """{resolution: {"method key": value}} of a `warpsph validate` file, with ``derived`` keys computed per row."""
    out = {}
    for row in load(name)["rows"]:
        flat = out.setdefault(str(row["resolution"]), {})
        for key, value in row.items():
            flat[f"{row['method']} {key}"] = value
        for key, f in derived.items():
            flat[f"{row['method']} {key}"] = f(row)
    return out


def row(name, method, resolution):
    return next(r for r in load(name)["rows"] if r["method"] == method and r["resolution"] == resolution)


def find(data, key_pattern):
    """Every (key, scalar value) under ``data`` whose key matches ``key_pattern``."""
    if isinstance(data, dict):
        for key, value in data.items():
            if isinstance(value, (dict, list)):
                yield from find(value, key_pattern)
            elif re.search(key_pattern, key, re.I):
                yield key, value
    elif isinstance(data, list):
        for value in data:
            yield from find(value, key_pattern)


# --- the files -----------------------------------------------------------------------------------------------------

def test_main_keeps_at_most_20_result_files_and_the_docs_name_only_kept_or_archived_ones():
    missing = [name for name in KEPT if not (RESULTS / name).is_file()]
    assert not missing, f"kept result files deleted: {missing}"
    assert len(KEPT) + 1 <= MAX_FILES
    ignore = [line.strip() for line in (RESULTS / ".gitignore").read_text().splitlines()
              if line.strip() and not line.startswith("#")]
    assert "*" in ignore
    assert sorted(line[1:] for line in ignore if line.startswith("!")) == sorted((".gitignore", *KEPT))
    if IN_GIT:
        tracked = git("ls-files", "tools/results").split()
        assert len(tracked) <= MAX_FILES, tracked
        assert sorted(Path(t).name for t in tracked) == sorted((".gitignore", *KEPT))
    # every result file the user pages name is kept here or on the results branch (where this clone has it)
    archived = set((git("ls-tree", "-r", "--name-only", "results", "tools/results/") or "").split())
    pages = [*DOCS.glob("*.md"), *(DOCS / "models").glob("*.md")]
    named = set()
    for p in pages:
        text = p.read_text()
        for m in re.finditer(r"tools/results/([\w.{},*-]+)", text):
            named.add(m.group(1).rstrip(".,"))
        named.update(re.findall(r"`([\w.-]+_(?:h100|h200|cpu|session\d+)[\w.-]*\.(?:json|md))`", text))
    for name in sorted(named):
        if name.startswith(("*", ".")) or name.isupper():  # tools/results/*.json, `..._X.json` (shortened), NAME
            continue
        expanded = [name]
        brace = re.search(r"\{([^}]*)\}", name)
        if brace:
            expanded = [name[:brace.start()] + part + name[brace.end():] for part in brace.group(1).split(",")]
        for one in expanded:
            pattern = re.compile(re.escape(one).replace(r"\*", ".*") + "$")
            here = any(pattern.match(k) for k in KEPT)
            there = any(pattern.match(Path(a).name) for a in archived)
            if archived:
                assert here or there, f"the docs name {one}, in neither tools/results/ nor the results branch"
            elif not here:  # a clone without the results branch: it must at least not be a kept name's typo
                assert not any(pattern.match(k) for k in KEPT)


def pinned_warp():
    """(lowest, below) of the warp-lang requirement in pyproject.toml, as tuples."""
    spec = re.search(r'"warp-lang>=([\d.]+),<([\d.]+)"', (ROOT / "pyproject.toml").read_text())
    as_tuple = lambda v: tuple(int(p) for p in v.split("."))  # noqa: E731
    return as_tuple(spec.group(1)), as_tuple(spec.group(2))


@pytest.mark.parametrize("name", KEPT)
def test_a_kept_file_is_a_measurement_naming_its_device_warp_and_commit(name):
    text = (RESULTS / name).read_text()
    data = json.loads(text)
    assert isinstance(data, dict) and data
    devices = [v for _, v in find(data, r"^device") if isinstance(v, str)]
    devices += re.findall(r"NVIDIA [A-Z]\d+[\w ]*", json.dumps(data))
    assert any(re.search(r"NVIDIA|cpu|CPU", d) for d in devices), f"{name} names no device"
    warps = [v for k, v in find(data, r"^warp$") if isinstance(v, str)]
    warps += re.findall(r"Warp (\d+\.\d+\.\d+)", text)
    assert warps, f"{name} names no Warp version"
    low, below = pinned_warp()
    for version in set(warps):
        parts = tuple(int(p) for p in version.split(".")[:len(low)])
        assert low <= parts < below, f"{name}: Warp {version} is outside warpsph's requirement"
    commits = [v for _, v in find(data, r"commit") if isinstance(v, str)]
    commits += re.findall(r"commit ([0-9a-f]{7,40})", text)
    hashes = {h for c in commits for h in re.findall(r"\b[0-9a-f]{7,40}\b", c)}
    assert hashes, f"{name} names no commit"
    if IN_GIT and git("rev-parse", "--is-shallow-repository") == "false\n":
        for h in sorted(hashes):
            assert git("cat-file", "-e", f"{h}^{{commit}}") is not None, f"{name}: commit {h} is not in this repository"


# --- the numbers the docs quote ------------------------------------------------------------------------------------

def test_the_validation_results_table_is_the_files():
    text = page("validation.md")
    tg = by_resolution("validate_taylor-green_h200.json")
    tg256 = row("validate_taylor-green_256_h100_37.json", "dfsph", 256)
    lo = "validate_lamb-oseen_models_session20_h100.json"
    vs = "validate_vortex-surface_h200_216628b.json"
    across = (64, 128, 256)
    rest = load("rest_32_session21_h100.json")["validation_adopted_surface_only"]["standing-wave"]
    vortices = load("validate_vortices_session20_h100.json")
    wave256 = row("validate_standing-wave_256_h200.json", "dfsph", 256)
    decay = lambda r: r["decay_rate"] / r["decay_rate_theory"]  # noqa: E731
    quoted = {
        "Taylor–Green, L1": (tg["64"]["dfsph error_pct"], tg["128"]["dfsph error_pct"], tg256["error_pct"]),
        "Lamb–Oseen (no surface), L1": tuple(row(lo, "dfsph", n)["error_pct"] for n in (64, 128, 256)),
        "Lamb–Oseen, peak vorticity": tuple(row(lo, "dfsph", n)["omega_ratio"] for n in (64, 128, 256)),
        "Lamb–Oseen, kinetic energy": tuple(row(lo, "dfsph", n)["ke_exact_ratio"] for n in (64, 128, 256)),
        "vortex below a free surface, L1": tuple(row(vs, "dfsph", n)["error_pct"] for n in (64, 128, 256)),
        "vortex below a free surface, kinetic energy": tuple(row(vs, "dfsph", n)["ke_exact_ratio"] for n in across),
        "vortex below a free surface, peak vorticity": tuple(row(vs, "dfsph", n)["omega_ratio"] for n in across),
        "standing wave, |frequency error|": (
            abs(rest["frequency_error_pct"]),
            vortices["same_lease_b47a492_vs_stress_patch"]["standing_wave_128_frequency_error_pct"]["stress"],
            abs(wave256["frequency_error_pct"])),
        "standing wave, amplitude decay": (
            decay(rest), decay(vortices["stress_viscosity_other_cases"]["standing_wave_128"]), decay(wave256)),
    }
    table = table_after(text, "**On the GPU**")
    seen = set()
    for cells in table:
        label = cells[0].replace("\\|", "|")
        key = next((k for k in quoted if label.startswith(k)), None)
        assert key is not None, f"docs/validation.md: a results row no file backs: {label}"
        seen.add(key)
        for shown, value in zip((numbers(c)[0] for c in cells[1:4]), quoted[key]):
            assert agrees(shown, value), f"docs/validation.md, {key}: the docs say {shown}, the file {value}"
        # the file column: each file named is kept and its commit is the file's
        for name, inside in re.findall(r"`([\w.-]+\.json)` \(([^)]*)\)", cells[-1]):
            assert name in KEPT, name
            commit = json.dumps(load(name).get("commit", ""))
            for h in re.findall(r"\b[0-9a-f]{7}\b", inside):
                assert h in commit or h in (RESULTS / name).read_text(), f"{name}: the docs say {h}"
    assert seen == set(quoted)


def test_the_cost_against_accuracy_tables_are_the_files():
    text = page("validation.md")
    methods = (("dfsph error_pct", "dfsph wall_s"), ("vr error_pct", "vr wall_s"),
               ("rankine error_pct", "rankine wall_s"), ("micropolar error_pct", "micropolar wall_s"))
    check_table(text, "Below a free surface:", by_resolution("validate_vortex-surface_models_h100.json"),
                methods, "vortex-surface models")
    check_table(text, "Lamb–Oseen (full tank):", by_resolution("validate_lamb-oseen_models_session20_h100.json"),
                methods, "lamb-oseen models")
    tg = by_resolution("validate_taylor-green_h200.json", per_second=lambda r: r["wall_s"] / 0.3)  # T = 0.3 s
    table = check_table(text, "**Taylor–Green** (periodic box", tg,
                        [(f"{m} error_pct", f"{m} per_second") for m in ("dfsph", "vr", "rankine", "micropolar")],
                        "Taylor-Green models")
    for cells in table:  # "64 (24,576)": the particles too
        resolution, particles = numbers(cells[0])[:2]
        assert int(particles) == tg[resolution]["dfsph particles"]


def test_the_performance_numbers_are_the_files():
    text = page("validation.md")
    bench = load("bench_dam_break_1M_models_h100.json")["results"]
    check_table(text, "**1M dam break**", {"none": bench["none"], "vorticity refinement": bench["vorticity_refinement"],
                                          "Rankine": bench["rankine"]},
                [("ms_per_step",), ("mean_density_iterations", "mean_divergence_iterations"), ("k_passes",),
                 ("bytes_per_fluid_particle_device",)], "1M dam break")
    stages = bench["none"]["ms_per_step_by_stage_synchronised"]
    quote = (f"neighbours {stages['neighbours']:.2f}, density pass {stages['density']:.2f}, divergence solve "
             f"{stages['divergence_solve']:.2f},\nviscosity {stages['non_pressure']:.2f}, density solve "
             f"{stages['density_solve']:.2f}, integration and shift {stages['integration']:.2f}")
    assert " ".join(quote.split()) in " ".join(text.split()), quote

    ms = {(r["fluid_particles"], r["gpus"], r["subdomains"]): r["ms_per_step"]
          for r in load("scaling_h200x4.json")["rows"]}
    table = table_after(text, "**Four NVIDIA H200**")
    one, two, four = ms[(31689503, 1, 1)], ms[(31689503, 2, 2)], ms[(31689503, 4, 4)]
    shown = [numbers(c) for c in table[0][1:4]]
    assert table[0][0] == "31.7M"
    for (number, *speedup), value in zip(shown, (one, two, four)):
        assert agrees(number, value)
        if speedup:
            assert agrees(speedup[0], one / value)
    for cell, value in zip(table[1][2:4], (ms[(63710026, 2, 2)], ms[(63710026, 4, 4)])):
        assert agrees(numbers(cell)[0], value)
    assert agrees(numbers(table[2][3])[0], ms[(199794688, 4, 8)])

    backends = load("scaling_mpi_h200x4.json")
    table = table_after(text, "**One process per GPU (MPI)**")
    for row, kind in zip(table, ("threads", "mpi")):
        runs = backends[kind]
        for cell, n in zip(row[1:4], ("1", "2", "4")):
            number, *speedup = numbers(cell)
            assert agrees(number, runs[n]["ms_per_step"]), (kind, n)
            if speedup:
                assert agrees(speedup[0], runs[n]["speedup_vs_1"]), (kind, n)
    weak = backends["weak_32M_per_gpu"]["runs"]
    quoted = re.search(r"Weak scaling at 32M a GPU.*?\(goal", " ".join(text.split())).group(0)
    for n in ("2", "4"):
        assert f"{weak[n]['ms_per_step']:.1f} ms" in quoted and f"**{100 * weak[n]['efficiency']:.0f} %**" in quoted, n

    multi = load("multi_gpu_h200x2.json")["summary"]
    check_table(text, "**Two NVIDIA H200**", {
        "7.9M": {"one": multi["ms_per_step"]["8M, 1 GPU"], "two": multi["ms_per_step"]["8M, 2 GPUs"],
                 "speedup": multi["strong_scaling_8M"]},
        "31.7M": {"one": multi["ms_per_step"]["32M, 1 GPU"], "two": multi["ms_per_step"]["32M, 2 GPUs"],
                  "speedup": multi["strong_scaling_32M"]}},
        [("one",), ("two",), ("speedup",)], "two H200")

    vs = load("vs_splishsplash_1M_h100.json")["session12"]
    for where in (text, page("splishsplash.md")):
        where = " ".join(where.split())
        per_second = re.search(r"(\d+)x per simulated second over the first 0\.2 s", where).group(1)
        per_step = re.search(r"(\d+)x a step", where).group(1)
        assert agrees(per_second, vs["ratio_per_simulated_second"]) and agrees(per_step, vs["ratio_per_step"])


def test_the_cases_paragraphs_quote_their_files():
    text = page("validation.md")
    rest = load("rest_32_session21_h100.json")
    dam20 = rest["validation_adopted_surface_only"]["dam-front"]
    dam40 = row("validate_dam-front_h100_37.json", "dfsph", 40)
    tanks = {t["fill"]: t["max_speed_last_second_over_sqrt_gH_pct"] for t in rest["adopted_surface_only_T5"]}
    vortices = load("validate_vortices_session20_h100.json")["same_lease_b47a492_vs_stress_patch"]
    spheres = load("validate_sinking-sphere_h200.json")["rows"]
    sphere = {(r["resolution"], r["boundary_viscosity"]): r for r in spheres}
    # the worst tank at each resolution
    density = [abs(r["density_error_mean_pct"]) for r in load("validate_tank-at-rest_h200.json")["rows"]]
    quotes = [  # (a passage of docs/validation.md, the values of its numbers in order; None: not from a file)
        ("RMS 0.344 a at 20 across", [dam20["front_rms_raw"], None]),
        ("0.338 a at 40 (ecc1ad5, `validate_dam-front_h100_37.json`)", [dam40["front_rms_raw"], None]),
        ("With the best time shift (−0.235 / −0.23 T) 0.085 / 0.086 a",
         [dam20["time_shift_T"], dam40["time_shift_T"], dam20["front_rms_shifted"], dam40["front_rms_shifted"]]),
        ("32 across: **12.2 / 17.5 / 8.8 / 13.5 %**", [None, tanks[1.0], tanks[0.95], tanks[0.93], tanks[0.88]]),
        ("16 across: 0.95 % for the worst of the four", [None, vortices["tank_at_rest_16_worst_pct"]["stress"]]),
        ("mean density error 0.004 % at 25 across", [vortices["hydrostatic_25_density_error_pct"]["stress"], None]),
        ("speed **1.077 / 1.035** × the middle of the reference band (0.133–0.140 m/s) at 5 / 10 particles",
         [sphere[5, 0.1]["speed_over_reference"], sphere[10, 0.1]["speed_over_reference"],
          sphere[5, 0.1]["reference_band"][0], sphere[5, 0.1]["reference_band"][1], None, None]),
        ("(40K / 323K particles, 3,818 / 16,029 steps)", [sphere[5, 0.1]["steps"], sphere[10, 0.1]["steps"]]),
        ("the same lease gave 1.233 at 5 across", [sphere[5, 0.05]["speed_over_reference"], None]),
        ("mean density error 0.01–0.03 %", [min(density), max(density)]),
    ]
    flat = " ".join(text.split())
    for passage, values in quotes:
        assert " ".join(passage.split()) in flat, f"docs/validation.md no longer says: {passage}"
        shown = numbers(passage)
        assert len(shown) == len(values), passage
        for number, value in zip(shown, values):
            if value is not None:
                assert agrees(number, value), f"docs/validation.md, {passage}: {number} against {value}"


def test_the_papers_latest_tables_are_the_files():
    text = page("papers.md")
    fig7 = {r["method"]: r for r in load("vr_fig7_h200_37.json")["rows"]}
    labels = {"DFSPH": "DFSPH", "noise: DFSPH, ν = 0.0501": "DFSPH, fluid.viscosity = 0.0501",
              **{f"VR α = {a}": f"VR alpha = {a.rstrip('0').rstrip('.')}" for a in ("1.0", "1.1", "1.2", "1.3")},
              **{f"micropolar ν_t = {n}": f"micropolar nu_t = {n}" for n in ("0.05", "0.1", "0.2", "0.3", "0.4")}}
    table = check_table(text, "`tools/results/vr_fig7_h200_37.{json,md}`", {d: fig7[j] for d, j in labels.items()},
                        [(f"E/E_DFSPH t={t}",) for t in (2, 4, 6, 8, 10)]
                        + [("mean E/E_DFSPH [2,8]",), ("E[9,10] / E_DFSPH[9,10]",), ("E_max (J)",), ("settled",)],
                        "VR Fig 7")
    assert len(table) == len(fig7)

    fig11 = {r["method"]: r for r in load("rankine_fig11_h200_37.json")["rows"]}
    labels = {"IISPH": "IISPH", "DFSPH": "DFSPH",
              **{f"{doc} ({s})": f"{js}{' (IISPH)' if s == 'IISPH' else ''}" for s in ("IISPH", "DFSPH")
                 for doc, js in (("micropolar ν_t = 0.05", "micropolar nu_t = 0.05"),
                                 ("Rankine β = 0.6", "Rankine beta = 0.6"))}}
    table = check_table(text, "`tools/results/rankine_fig11_h200_37.{json,md}`",
                        {d: fig11[j] for d, j in labels.items()},
                        [("peak E (J)",), ("peak / baseline peak",)] + [(f"E/E_base t={t}",) for t in (1, 2, 4, 6, 8)]
                        + [("E_end (J)",), ("E_end / baseline E_end",), ("E_rot peak (J)",), ("E_rot end (J)",)],
                        "Rankine Figs 11-12")
    assert len(table) == len(fig11)

    table1 = {r["experiment"]: r for r in load("vr_table1_h100.json")["rows"]}
    table = check_table(text, "`tools/results/vr_table1_h100.{json,md}`",
                        {f"{e} ({r['figure']})": r for e, r in table1.items()},
                        [("particles",), ("DFSPH ms/step",), ("MP ms/step",), ("VR ms/step",), ("MP overhead %",),
                         ("VR overhead %",), ("paper MP overhead %", "paper VR overhead %")], "VR Table 1")
    assert len(table) == len(table1)
