"""Regenerate README.md's and the book page book/running.md's result and benchmark tables from the committed data
(never typed by hand).

Each table sits between ``<!-- begin:NAME -->`` and ``<!-- end:NAME -->`` markers in README.md and is rendered
from ``figures/data/*.json`` (the figure baselines' data) or ``benchmarks/bench_dpe.json``:

    python scripts/readme_tables.py            # rewrite README.md in place
    python scripts/readme_tables.py --check    # exit 1 and name the stale tables if README.md is out of date

``tests/test_readme.py`` runs the check, so a changed baseline without a regenerated README fails ``make test``.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
#: the book page with the operating depth (layout, command line, store, cache, Dask, GPU, benchmarks)
RUNNING = ROOT / "book" / "running.md"
#: the book's landing page
INTRO = ROOT / "book" / "intro.md"
#: the generated blocks of each file
README_BLOCKS = ("found", "chapters", "timing_short")
INTRO_BLOCKS = ("found_book",)
RUNNING_BLOCKS = ("timing", "durations", "fig9", "fig10", "readings", "gpu", "bench", "engine", "store", "coverage", "cluster",
                  "trace")


def _load(rel: str) -> dict:
    return json.loads((ROOT / rel).read_text())


def fig9_table() -> str:
    p = _load("figures/data/fig09_rmse_vs_snr.json")
    c, d = p["config"], p["data"]
    ms, snrs = c["m_values"], c["snrs_db"]
    rec = c["receivers"]
    head = "| SNR per sample (dB) | " + " | ".join(f"M = {m}" for m in ms) + " |"
    lines = [f"RMSE (m) of the honest receiver ({rec['honest']['n_trials']} trials per point; in brackets the "
             f"paper's truth-centred grid, {rec['truth']['n_trials']} trials), receiver window L = "
             f"{rec['honest']['n_taps']}, LoS share of the 24 nearest links {100 * d['los_share_all']:.1f} %:", "",
             head, "|---" * (len(ms) + 1) + "|"]
    for i, s in enumerate(snrs):
        lines.append(f"| {s:g} | " + " | ".join(f"{d['honest']['rmse_m'][i][j]:.2f} ({d['truth']['rmse_m'][i][j]:.2f})"
                                                for j in range(len(ms))) + " |")
    edge = max(max(r) for r in d["honest"]["edge_share"])
    cert = min(min(r) for r in d["honest"]["certified_share"])
    lines += ["", f"Honest receiver: at most {100 * edge:.1f} % of fixes flagged on the window's edge, at least "
                  f"{100 * cert:.0f} % certified (gap ≤ 1e-4) per point."]
    return "\n".join(lines)


def fig10_table() -> str:
    p = _load("figures/data/fig10_cdf_dpe_vs_otdoa.json")
    d, ex = p["data"], p["config"]["experiments"]
    names = [("dpe_otdoa", "DPE centred on the OTDoA fix (honest, main)"), ("dpe_prior", "DPE centred on a 5 m prior (honest)"),
             ("dpe_truth", "DPE centred on the truth (paper's set-up)"), ("otdoa_first_path", "OTDoA, first-path ToA (main baseline)"),
             ("otdoa_peak", "OTDoA, strongest-peak ToA (naive)")]
    cases = [("two_of_four", "(a) 2 of 4 LoS"), ("pr_los", "(b) LoS from eq. (11)")]
    lines = [f"Horizontal error p50 / p90 / p99 (m), 4 nearest BSs, SNR per link from the path loss, "
             f"{ex['pr_los/otdoa']['n_trials']} trials per case; in brackets the share of fixes flagged (DPE: on the "
             "window's edge; OTDoA: solver or polish failure):", "",
             "| receiver | " + " | ".join(lab for _, lab in cases) + " |", "|---|---|---|"]
    for key, lab in names:
        cells = []
        for case, _ in cases:
            r = d[case][key]
            q = r["p50_p90_p99_m"]
            flag = r.get("edge_share", r.get("flagged_share"))
            cells.append(f"{q[0]:.2f} / {q[1]:.2f} / {q[2]:.1f} ({100 * flag:.1f} %)")
        lines.append(f"| {lab} | " + " | ".join(cells) + " |")
    lines.append("| OTDoA first-path, flagged fixes left out | " + " | ".join(
        "{:.2f} / {:.2f} / {:.1f}".format(*d[case]["otdoa_first_path"]["p50_p90_p99_unflagged_m"]) for case, _ in cases)
        + " |")
    lines.append("| improvement 1 − p90(DPE on OTDoA fix) / p90(OTDoA first path); paper 95.24 % | " + " | ".join(
        f"{100 * d[case]['improvement_p90']:.1f} %" for case, _ in cases) + " |")
    return "\n".join(lines)


def bench_table() -> str:
    b = _load("benchmarks/bench_dpe.json")
    s, r = b["seconds"], b["ratios"]
    ms = lambda x: f"{1e3 * x:.3g} ms"
    rows = [
        ("eq. (10) literal (explicit matrices), per BS and candidate, N = 4096", ms(s["literal_per_bs_candidate"]), ""),
        ("eq. (10) fast, one FFT per candidate (`cost.ml_cost`), per BS and candidate",
         ms(s["fast_per_bs_candidate"]), ""),
        ("speed-up `ml_cost` / literal (agreement {:.1e})".format(b["fast_vs_literal_max_rel_diff"]),
         f"{r['fast_vs_literal']:.0f}×", ""),
        ("speed-up correlogram grid / literal", f"{r['correlogram_vs_literal']:.2g}×", "≥ 1000×"),
        ("one grid fix (truth-centred comparison), M = 24, ±10 m, to 0.1 m", ms(s["fix_m24"]), "≤ 20 ms"),
        ("one **honest** fix, M = 24, certified search, ±30 m × ±30 m, c·δt ±4.5 m (spline correlograms included); "
         f"median of {len(s['honest_fix_m24_rounds'])} rounds (range)",
         f"{ms(s['honest_fix_m24'])} ({ms(min(s['honest_fix_m24_rounds']))}–{ms(max(s['honest_fix_m24_rounds']))})",
         "≤ 20 ms"),
        ("  its parts (jitted): the 24 spline correlograms / the branch and bound",
         f"{ms(s['spline_correlograms_m24'])} / {ms(s['bnb_m24'])}", ""),
        ("one 4096-point FFT (the floor)", ms(s["fft_4096"]), ""),
        ("honest fix / one FFT", f"{r['honest_fix_vs_fft']:.0f}×", ""),
        ("per-BS share of a grid fix / one FFT", f"{r['per_bs_vs_fft']:.1f}×", ""),
    ]
    m = b["machine"]
    lines = [f"`benchmarks/bench_dpe.py` on {m['cpus']} CPUs ({m['platform']}, JAX {m['jax']}, float64), medians "
             "after jit:", "", "| quantity | measured | target |", "|---|---|---|"]
    lines += [f"| {a} | {v} | {t} |" for a, v, t in rows]
    return "\n".join(lines)


def gpu_table() -> str:
    """The running page's GPU measurements (``benchmarks/gpu_h200.json``) beside this machine's CPU benchmarks."""
    g, cpu_d, cpu_e = (_load(f"benchmarks/{n}.json") for n in ("gpu_h200", "bench_dpe", "bench_engine"))
    gd, ge = g["bench_dpe"], g["bench_engine"]
    ms = lambda x: f"{1e3 * x:.3g} ms"
    h_cpu = cpu_d["seconds"]["honest_fix_m24_rounds"]
    f9h = cpu_e["fig9_honest"]
    rows = [
        ("one honest fix, M = 24, certified search (median of 5 rounds)", ms(gd["seconds"]["honest_fix_m24"]),
         f"{ms(min(h_cpu))}–{ms(max(h_cpu))}"),
        ("one grid fix (truth-centred comparison), M = 24", ms(gd["seconds"]["fix_m24"]), ms(cpu_d["seconds"]["fix_m24"])),
        ("Fig. 9 honest, per trial (7 SNRs × 4 M)", ms(ge["fig9_honest"]["per_trial_s_one_thread"]),
         f"{ms(f9h['per_trial_s_workers'])}–{ms(f9h['per_trial_s_one_thread'])}"),
        ("Fig. 9 truth-centred, per trial (7 SNRs)", ms(ge["fig9_empty_cache"]["per_trial_s"]),
         ms(cpu_e["fig9_empty_cache"]["per_trial_s"])),
        ("Fig. 9 truth-centred, 5000 trials", f"{ge['fig9_empty_cache']['full_5000_s']:.1f} s (extrapolated)",
         f"{cpu_e['fig9_empty_cache']['full_5000_s']:.0f} s"),
        ("per-BS share of a grid fix, in FFTs", f"{gd['ratios']['per_bs_vs_fft']:.1f}",
         f"{cpu_d['ratios']['per_bs_vs_fft']:.1f}"),
    ]
    v = g["verify_all"]
    lines = [f"Measured on one {g['gpu']} ({ge['machine']['cpus']} CPUs beside it, JAX {ge['machine']['jax']} with CUDA, "
             f"float64) at commit {g['commit']}, with `benchmarks/bench_dpe.py` and `benchmarks/bench_engine.py` "
             f"(`benchmarks/gpu_h200.json`); the CPU column is this page's benchmarks on "
             f"{cpu_d['machine']['cpus']} CPUs:", "", "| quantity | GPU | CPU |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines += ["", f"`{v['command']}` on the GPU recomputed {v['experiments_recomputed']} of {v['experiments']} "
              f"experiments in {v['seconds']} s without finishing: each experiment compiles its own programs, and "
              "the compiles, not the Monte Carlo, take the time."]
    return "\n".join(lines)


#: issue 11's target for a fresh ``make test`` (the project's own budget, in ``timing_text``, is 20 minutes)
FRESH_TEST_TARGET_S = 600


def engine_table() -> str:
    b = _load("benchmarks/bench_engine.json")
    s, r, f9 = b["seconds"], b["ratios"], b["fig9_empty_cache"]
    ms = lambda x: f"{1e3 * x:.3g} ms"
    rows = [
        ("one 4096-point FFT: one call (with dispatch) / per row of 24 in one call",
         f"{ms(s['fft_4096_call'])} / {ms(s['fft_4096_row'])}", ""),
        ("**the engine's** grid correlogram per BS and SNR (L = 12, U = 4; parts once per trial for its 7 SNRs, "
         "energies in the search's window, complex64), per-row FFT-equivalents",
         f"{ms(s['grid_engine_per_bs_snr'])} ({r['grid_engine_vs_fft_row']:.1f}×)", "≤ 3×"),
        ("**the engine's** spline correlogram per BS and SNR (certified search, U = 8; parts once per trial for its "
         "7 SNRs, float64), per-row FFT-equivalents",
         f"{ms(s['spline_engine_per_bs_snr'])} ({r['spline_engine_vs_fft_row']:.1f}×)", ""),
        ("one whole grid correlogram from one LS spectrum, complex128: time; FFT-equivalents one-call / per-row",
         f"{ms(s['grid_correlogram_per_bs'])}; {r['grid_correlogram_vs_fft_call']:.1f}× / "
         f"{r['grid_correlogram_vs_fft_row']:.1f}×", ""),
        ("  the same in complex64 (`correlogram.GRID_DTYPE`), per-row FFT-equivalents",
         f"{ms(s['grid_correlogram_per_bs_c64'])} ({r['grid_correlogram_c64_vs_fft_row']:.1f}×)", ""),
        ("  ToA error complex64 adds to the OTDoA peak (max over 24 links)", f"{b['c64_toa_error_mm']:.2g} mm",
         "< 1 mm"),
        ("one whole spline correlogram from one LS spectrum (U = 8), per-row FFT-equivalents",
         f"{ms(s['spline_correlogram_per_bs'])} ({r['spline_correlogram_vs_fft_row']:.1f}×)", ""),
        ("Fig. 9 truth-centred, per (trial, SNR): draws + noise / the correlogram parts of 24 BSs / 4 grid searches",
         " / ".join(ms(s[k]) for k in ("fig9_draw_per_trial_snr", "fig9_correlograms_per_trial_snr",
                                       "fig9_searches_per_trial_snr")), ""),
        ("Fig. 9 truth-centred from empty caches: compile + first 100 trials", f"{f9['first_chunk_s']:.0f} s", ""),
        (f"Fig. 9 truth-centred, all 5000 trials ({'measured' if f9['full_measured'] else 'extrapolated from ' + str(f9['trials'])})",
         f"{f9['full_5000_s']:.0f} s", "≤ 120 s"),
    ]
    h = b.get("fig9_honest")
    if h:
        rows.append((f"Fig. 9 honest receiver (certified search), per trial of 7 SNRs × 4 M: one thread / "
                     f"{h['workers']} threads (`DPE5G_WORKERS`; {h['trials']} trials each)",
                     f"{ms(h['per_trial_s_one_thread'])} / {ms(h['per_trial_s_workers'])}", ""))
    o = b.get("otdoa_fix_s")
    if o:
        rows.append(("OTDoA fix (M = 4, no polish): cvxpy's `Problem.solve` / `otdoa.Solver.solve` (the data map read "
                     "from cvxpy once, then Clarabel)", f"{ms(o['problem_solve'])} / {ms(o['solver'])}", ""))
    if (ROOT / "benchmarks/bench_figures.json").exists():
        f = _load("benchmarks/bench_figures.json")
        slow = sorted(f["per_figure_s"].items(), key=lambda kv: -kv[1])[:3]
        rows.append(("`dpe5g figures` from empty caches and the results store, every figure (`benchmarks/bench_figures.py`; slowest: "
                     + ", ".join(f"{k} {v:.0f} s" for k, v in slow) + ")",
                     f"{f['wall_s']:.0f} s (CPU {f['cpu_s']:.0f} s)", f"≤ {f['target_s']:.0f} s"))
    fc = _load("benchmarks/fresh_check.json")
    rows.append((f"fresh `make test` (a clean clone at {fc['commit']}, the timing below)",
                 f"{fc['make_test_s']} s", f"≤ {FRESH_TEST_TARGET_S} s"))
    whole = [("the figure build", f["wall_s"], f["target_s"])] if (ROOT / "benchmarks/bench_figures.json").exists() else []
    whole.append(("a fresh `make test`", fc["make_test_s"], FRESH_TEST_TARGET_S))
    verdict = "; ".join(f"{name} {'meets' if v <= tgt else 'misses'} its target ({v:.0f} s against {tgt:.0f} s)"
                        for name, v, tgt in whole)
    m = b["machine"]
    lines = [f"`benchmarks/bench_engine.py` on {m['cpus']} CPUs ({m['platform']}, JAX {m['jax']}, float64):", "",
             "| quantity | measured | target |", "|---|---|---|"]
    lines += [f"| {a} | {v} | {t} |" for a, v, t in rows]
    lines += ["", f"Whole builds on this machine: {verdict}."]
    return "\n".join(lines)


def timing_text() -> str:
    b = _load("benchmarks/fresh_check.json")
    ch = sorted(b["chapters_s"].items(), key=lambda kv: -kv[1])
    budget = 10 * 60  # the target since the results store (issue 31)
    verdict = (f"within the project's {budget // 60}-minute target" if b["make_test_s"] <= budget
               else f"above the project's {budget // 60}-minute target")
    return (f"Measured on a clean clone (no `.venv`, no cache) at {b['commit']} on "
            f"{b['machine']['cpus']} CPUs: `make test` {b['make_test_s']} s ({b['make_test_s'] // 60} min "
            f"{b['make_test_s'] % 60} s), {verdict}; {b['tests_passed']} tests passed"
            + (f", {b['tests_skipped']} skipped" if b["tests_skipped"] else "")
            + (f", the pytest suite {b['pytest_s']:.0f} s; " if len(b.get("pytest_runs_s", [])) != 2 else
               f"; pytest {b['pytest_runs_s'][0]:.0f} s for the tests that need no book (at low priority, from the "
               f"start) and {b['pytest_runs_s'][1]:.0f} s for those in `tests/book/` (once it is built, beside them); ")
            + "chapter execution: " + ", ".join(f"{k} {v:.0f} s" for k, v in ch) + ".  "
            + (f"`make book` alone (a clean clone, at {b['make_book_commit']}): {b['make_book_s']} s "
               f"({b['make_book_s'] // 60} min {b['make_book_s'] % 60} s), "
               f"{'within' if b['make_book_s'] <= 300 else 'above'} the 5-minute target.  " if "make_book_s" in b else "")
            + "`scripts/fresh_check_times.py` records these from the clean clone's logs.")


def durations_table() -> str:
    b = _load("benchmarks/fresh_check.json")
    if "slowest_tests" not in b:
        return f"Not recorded at {b['commit']} (`scripts/fresh_check_times.py` records them since 2026-12-07)."
    rows = "\n".join(f"| {secs:.1f} | {phase} | `{test}` |" for secs, phase, test in b["slowest_tests"])
    return (f"The {len(b['slowest_tests'])} slowest test phases of that `make test` (pytest's `--durations`, at "
            f"{b['commit']}; the tests that need no book ran beside the book's build, at low priority):\n\n"
            f"| s | phase | test |\n|---:|---|---|\n{rows}")


def timing_short() -> str:
    b = _load("benchmarks/fresh_check.json")
    book = (f"`make book` {b['make_book_s']} s ({b['make_book_s'] // 60} min {b['make_book_s'] % 60} s, at "
            f"{b['make_book_commit']}), " if "make_book_s" in b else "")
    return (f"On a clean clone with {b['machine']['cpus']} CPUs: {book}`make test` {b['make_test_s']} s "
            f"({b['make_test_s'] // 60} min {b['make_test_s'] % 60} s, {b['tests_passed']} tests, at {b['commit']}).")


def found_text(book: bool = False) -> str:
    """README's "What it found" (``book``: the landing page's, with links into the book): seven lines of numbers from
    the committed figure data, the results store and the book's errata list."""
    files = {m.group(1): f"`chapters/{p.name}`" for p in sorted((ROOT / "chapters").glob("*.md"))
             for m in [re.search(r"^\((chapter-[\w-]+)\)=$", p.read_text(), re.M)] if m}
    ref = lambda label, text: f"{{numref}}`{text} <{label}>`" if book else files[label]
    from dpe5g.figures import tables as report

    p9, p10 = _load("figures/data/fig09_rmse_vs_snr.json"), _load("figures/data/fig10_cdf_dpe_vs_otdoa.json")
    c, d = p9["config"], p9["data"]
    i_lo, i_hi = c["snrs_db"].index(min(c["snrs_db"])), c["snrs_db"].index(max(c["snrs_db"]))
    ms = c["m_values"]
    h = lambda i, m: d["honest"]["rmse_m"][i][ms.index(m)]
    r = p10["data"]["two_of_four"]
    readings = _load("figures/data/readings_table.json")
    s = report.readings_summary(readings)
    umi = readings["data"]["umi"]
    diff = umi["dpe_minus_otdoa_p90_m"]
    text = (ROOT / "chapters" / "07_reproduction.md").read_text()
    errata = text.split("## Errata and gaps found while reproducing", 1)[1].split("\n## ", 1)[0]
    n_errata = len(re.findall(r"^\d+\. \*\*", errata, re.M))
    lo, hi = min(c["snrs_db"]), max(c["snrs_db"])
    rm = [[v for v in row] for row in d["honest"]["rmse_m"]]  # (S, J)
    spread = max(100 * (max(col) - min(col)) / min(col) for col in zip(*rm))
    return "\n".join([
        f"- **Fig. 9** (RMSE against SNR, {ref('chapter-rmse', 'Chapter %s')}), honest receiver: "
        f"{h(i_lo, ms[0]):.2f} m at {lo:g} dB and "
        f"{h(i_hi, ms[0]):.2f} m at {hi:g} dB with M = {ms[0]}, {h(i_lo, ms[-1]):.2f} m and {h(i_hi, ms[-1]):.2f} m "
        f"with M = {ms[-1]}: it moves by at most {spread:.0f} % over {lo:g}–{hi:g} dB for any M, whereas the paper's "
        f"falls with the SNR (within 6 m at {lo:g} dB with M = 6, below 1 m at {hi:g} dB with M ≥ 18).",
        f"- **Fig. 10** (error CDF with the 4 nearest BSs, 2 of them LoS; {ref('chapter-otdoa', 'Chapter %s')}): 90 % "
        f"of DPE's errors within {r['dpe_otdoa']['p50_p90_p99_m'][1]:.2f} m when its search is centred on the OTDoA "
        f"fix, against {r['otdoa_first_path']['p50_p90_p99_m'][1]:.2f} m for first-path OTDoA: an improvement of "
        f"{100 * r['improvement_p90']:.0f} %, where the paper reports 95.24 %.",
        f"- **NLoS bias** (the paper's title claim; {ref('chapter-nlos', 'Chapter %s')}): with every NLoS link's paths "
        "late by TR 38.901's UMi excess delay (Table 7.6.9-1; the paper's model has none), the honest DPE's 90 % "
        f"error in Fig. 10's case is {umi['values']['fig10_dpe_p90']:.1f} m against first-path OTDoA's "
        f"{umi['values']['fig10_otdoa_p90']:.1f} m on the same {umi['n_trials']['fig10_dpe']} trials: a difference "
        f"of {diff[0]:+.1f} m, 95 % interval [{diff[1]:+.1f}, {diff[2]:+.1f}] m"
        + (" (unresolved: it holds 0)." if diff[1] <= 0 <= diff[2] else "."),
        city_line(ref),
        f"- **Claims**: of the paper's {s['n_claims']} claims about Figs. 9–10, judged by the 95 % interval of our "
        f"value: {claims_verdicts(s['verdicts'])}; none of the {len(s['counts'])} set-ups of our readings table "
        f"(readings of its unstated details, and our NLoS variants) reproduces more than {s['best']}.",
        f"- **Errata**: {n_errata} errata and gaps in the paper, from swapped channel profiles in Table I to an "
        "undefined SNR.",
        ("- **Where**: the claim-by-claim comparison and the errata are "
         + ("{numref}`Chapter %s <chapter-reproduction>`, *Reproduction summary and errata*." if book else
            "the book's chapter *Reproduction summary and errata* (`chapters/07_reproduction.md`; "
            "`book/_build/html/chapters/07_reproduction.html` after `make book`)."))])


def claims_verdicts(verdicts: dict) -> str:
    """The claims' verdicts under our reading of the paper's set-up and with the honest receiver, said once where
    they agree."""
    from dpe5g.figures import tables as report

    as_read, honest = (report.verdict_text(verdicts[k]) for k in ("as_read", "honest"))
    honest_words = "with the honest receiver (one that never sees the true position)"
    if as_read == honest:
        return f"{as_read}, both under our reading of its set-up and {honest_words}"
    return f"{as_read} under our reading of its set-up, {honest} {honest_words}"


@functools.lru_cache(maxsize=None)
def city_summary(city: str | None = None) -> dict:
    """``city_study.summary`` of ``city`` (None: the book's city), computed once per process: README and the landing
    page both show it (10 s each)."""
    from dpe5g.studies import city as city_study

    return city_study.summary(city_study.CITY if city is None else city)


def city_line(ref) -> str:
    """README's line on the ray-traced city (``city_study.summary``, from the results store)."""
    from dpe5g.studies import city as city_study

    c = city_summary()
    v, lo, hi = c["diff_p90"]
    verdict = "DPE better" if hi < 0 else "OTDoA better" if lo > 0 else "unresolved: it holds 0"
    name = lambda p: "not at all" if p is None else f"to {p * 1e9:.0f} ns"  # noqa: E731
    same = {}  # priors with the same verdicts, in the sweep's order
    for p, vs in c["verdicts"].items():
        if p != city_study.CITY_CLOCK_PRIORS_S[0]:
            same.setdefault(vs, []).append(name(p))
    told = "; ".join(f"told the clock {' or '.join(ps)}, {v50} at the median and {v90} at the 90 % point"
                     for (v50, v90), ps in same.items())
    traced = (f"diffuse reflection traced with a scattering coefficient of {c['scattering_coefficient']:g}"
              if c["scattering_coefficient"] > 0 else "diffuse reflection not traced")
    traced += ", refraction traced" if c["refraction"] else ", refraction not"
    return (f"- **Ray-traced city** (Sionna RT's Munich, the paper's density, {traced}; "
            f"{ref('chapter-city', 'Chapter %s')}): {c['hear_m_pct']:.0f} % of outdoor UEs hear four BSs.  "
            f"On {c['n_trials']} of them, with the UE clock known to 5 ns (the DPE's clock window "
            f"±{c['clock_half_m']:.1f} m), the honest DPE's 90 % error is {c['dpe_p90_m']:.1f} m against "
            f"{c['best_otdoa_p90_m']:.1f} m for the best OTDoA receiver given the same window ({c['best_otdoa']}; "
            f"first-path OTDoA {c['otdoa_p90_m']:.1f} m): a difference of {v:+.1f} m, 95 % interval "
            f"[{lo:+.1f}, {hi:+.1f}] m ({verdict}).  The answer depends on that clock: {told}.  On the trials' NLoS "
            f"links the first path within {-city_study.FIRST_PATH_THRESHOLD_DB:.0f} dB of the strongest is {c['excess_trial_ns']:.0f} ns late at the median, "
            f"against TR 38.901's UMi {c['umi_median_ns']:.0f} ns.  {density_sentence()}  {second_sentence()}")


def second_sentence() -> str:
    """README's sentence on the second city (``city_second``; ``city_study.summary``, from the results store)."""
    from dpe5g.studies import city as city_study, city_second

    c = city_summary(city_second.SECOND_CITY)
    name = lambda p: "told nothing" if p is None else f"told {p * 1e9:.0f} ns"  # noqa: E731
    said = "; ".join(f"{name(p)}, {c['best'][(p, 0.5)].verdict()} at the median "
                     f"({c['best'][(p, 0.5)].difference.text('+.1f')} m) and {c['best'][(p, 0.9)].verdict()} at the "
                     f"90 % point ({c['best'][(p, 0.9)].difference.text('+.1f')} m)"
                     for p in (city_study.CITY_CLOCK_PRIORS_S[0], None))
    return (f"In a second city, Sionna RT's Étoile (Paris: wide avenues; {c['n_ue']} UEs, the same settings), "
            f"{c['hear_m_pct']:.0f} % of the UEs hear four BSs; on {c['n_trials']} of them, the best DPE against the "
            f"best OTDoA: {said}.")


def density_sentence() -> str:
    """README's sentence on the density sweep (``city_density.comparison``, from the results store)."""
    import numpy as np

    from dpe5g.city import dataset
    from dpe5g.studies import city as city_study, city_density

    hear, median = [], []
    for f in city_density.FACTORS:
        net = dataset.load_city(city_density.density_name(city_study.CITY, f))
        hear.append(f"{100 * np.mean(city_study.heard_per_ue(net) >= 4):.0f} %")
        b = city_density.comparison(f, city_density.DENSITY_CLOCK_PRIORS_S[0]).best[0]
        median.append(f"×{f} {b.verdict()} ({b.difference.text('+.1f')} m)")
    f = [str(k) for k in city_density.FACTORS]
    return (f"At {', '.join(f[:-1])} and {f[-1]} times the paper's density ({city_density.DENSITY_UES} UEs each), "
            f"{', '.join(hear[:-1])} and {hear[-1]} of the UEs hear four BSs; with the clock known to 5 ns, the best "
            f"DPE against the best OTDoA at the median: {'; '.join(median)}.")


def readings_table() -> str:
    from dpe5g.figures import tables as report

    p = _load("figures/data/readings_table.json")
    data, s = p["data"], report.readings_summary(p)
    best = ", ".join(f"*{data[n]['label']}*" for n in s["best_readings"])
    head = (f"No reading reproduces all {s['n_claims']} claims" if s["best"] < s["n_claims"]
            else "A reading reproduces every claim")
    return "\n".join([
        f"Each reading of the paper tested on its claims about Figs. 9 and 10 ({{numref}}`Chapter %s <chapter-reproduction>`; "
        "by the 95 % interval of our value: ✓ reproduces, ? unresolved, ✗ fails; "
        f"Fig. 9 at {', '.join(f'{v:g}' for v in p['config']['snrs_db'])} dB per the reading's SNR convention; the "
        "numbers, with their intervals, are in `figures/data/readings_table.json`):", "",
        "```{figure} ../figures/readings_table.png", ":name: fig-running-readings",
        ":alt: the readings of the paper against its claims about Figs. 9 and 10, with each value's verdict", "",
        "**Our table, not in the paper.** The readings of the paper against its claims about Figs. 9 and 10: the "
        "committed baseline `figures/readings_table.png`, drawn from `figures/data/readings_table.json`.", "```", "",
        f"{head}; the most, {s['best']} of {s['n_claims']}, by {best}.  Our reading of the paper's set-up: "
        f"{report.verdict_text(s['verdicts']['as_read'])}; the honest receiver: "
        f"{report.verdict_text(s['verdicts']['honest'])}."])


def store_text() -> str:
    metas = [json.loads(m.read_text()) for m in sorted((ROOT / "figures" / "trials").glob("*.json"))]
    size = sum(f.stat().st_size for f in (ROOT / "figures" / "trials").rglob("*") if f.is_file())
    city = sum(f.stat().st_size for f in (ROOT / "figures" / "trials" / "cities").iterdir())
    trials = sum(m["n_trials"] for m in metas)
    short = lambda c: "outside git" if not c else c[:7] + ("+changes" if "+" in c else "")
    versions = sorted({(m["code_version"], short(m["commit"])) for m in metas})
    return (f"Now: {len(metas)} entries, {trials} trials, and the traced city ({city / 1e6:.1f} MB in `cities/`), "
            f"{size / 1e6:.1f} MB in all (the budget is 50 MB); the entries computed by "
            f"code version{'s' if len(versions) > 1 else ''} "
            + ", ".join(f"`{v}` (commit {c})" for v, c in versions) + ".")


def coverage_text() -> str:
    from dpe5g.simulation import verify
    from dpe5g.studies import catalog

    n = len(verify.families(catalog.store_experiments()))
    mean, q95 = verify.coverage_runs(n, verify.SAMPLE_FAMILIES)
    return (f"The {len(catalog.store_experiments())} stored experiments fall into {n} families.  With "
            f"{verify.SAMPLE_FAMILIES} of them drawn per `make test`, every stored experiment has been verified at "
            f"least once after {mean:.1f} runs on average, and after {q95} runs with probability 95 % "
            f"(`verify.coverage_runs`; the chapters' own draws, one family each, only shorten this).")


def cluster_text() -> str:
    path = ROOT / "benchmarks" / "bench_cluster.json"
    if not path.exists():
        return "`benchmarks/bench_cluster.py` has not been run on this machine yet."
    b = json.loads(path.read_text())
    which = ", ".join(b["only"]) if b["only"] else "every stored experiment"
    lines = [f"`benchmarks/bench_cluster.py` on {b['machine']['cpus']} CPUs: {which} at {b['fraction']:g} of "
             f"the stored trial counts, from empty caches (the Monte Carlo and its compiles), every result compared "
             f"with the store:", "",
             "| set-up | wall (s) | differences from the store | peak memory per process (MB) |", "|---|---|---|---|"]
    for name, r in b["setups"].items():
        lines.append(f"| {name} | {r['wall_s']:.0f} | {r['differences']} | "
                     + ", ".join(f"{m:.0f}" for m in r["peak_rss_mb"]) + " |")
    return "\n".join(lines)


def trace_text() -> str:
    path = ROOT / "benchmarks" / "bench_trace.json"
    if not path.exists():
        return "`benchmarks/bench_trace.py` has not been run on this machine yet."
    b = json.loads(path.read_text())
    lines = [f"`benchmarks/bench_trace.py` on {b['machine']['cpus']} CPUs: {b['ues']} UEs × {b['bs']} BSs of "
             f"{b['scene']} at the book's settings, in calls of {b['batch']} UEs, from an empty trace cache (the scene "
             f"loaded and the UEs and BSs placed in {b['layout_s']:.0f} s, not counted):", "",
             "| set-up | wall (s) | links | links per second | the same bits as one thread |", "|---|---|---|---|---|"]
    for r in b["rows"]:
        same = {None: "–", True: "yes", False: "no"}[r["same_bits_as_one_thread"]]
        lines.append(f"| {r['setup']} | {r['seconds']:.0f} | {r['links']} | {r['links_per_s']:.2f} | {same} |")
    return "\n".join(lines)


def toc_pages() -> list[tuple[str, str]]:
    """The book's pages in ``book/_toc.yml``'s order, each (path of its source from the repository root, its title: the
    first ``# `` heading of the file)."""
    import yaml

    toc = yaml.safe_load((ROOT / "book" / "_toc.yml").read_text())
    pages = []
    for entry in [{"file": toc["root"]}] + toc["chapters"]:
        path = ROOT / f"{entry['file']}.md"
        title = next(line[2:].strip() for line in path.read_text().splitlines() if line.startswith("# "))
        pages.append((path.relative_to(ROOT).as_posix(), title))
    return pages


def chapters_text() -> str:
    """README's list of the book's pages from ``book/_toc.yml``: the numbered chapters (``chapters/``), then the pages
    after them, each with its source file."""
    pages = toc_pages()[1:]  # the landing page is the book itself
    chapters = [(p, t) for p, t in pages if p.startswith("chapters/")]
    rest = [(p, t) for p, t in pages if not p.startswith("chapters/")]
    lines = [f"{i}. {t} (`{p}`);" for i, (p, t) in enumerate(chapters, 1)]
    lines[-1] = lines[-1][:-1] + "."
    lines += ["", "After them, numbered on: " + "; ".join(f"*{t}* (`{p}`)" for p, t in rest) + "."]
    return "\n".join(lines)


TABLES = {"found": found_text, "chapters": chapters_text, "found_book": lambda: found_text(book=True), "timing_short": timing_short,
          "timing": timing_text, "fig9": fig9_table, "fig10": fig10_table, "bench": bench_table,
          "engine": engine_table, "readings": readings_table, "gpu": gpu_table, "store": store_text, "coverage": coverage_text,
          "cluster": cluster_text, "trace": trace_text, "durations": durations_table}


def render(text: str, names, where: str = "README.md") -> str:
    for name in names:
        pat = re.compile(rf"(<!-- begin:{name} -->\n)(?:.*?\n)?(<!-- end:{name} -->)", re.S)
        if not pat.search(text):
            raise ValueError(f"{where} has no <!-- begin:{name} --> … <!-- end:{name} --> block")
        text = pat.sub(lambda mt, fn=TABLES[name]: mt.group(1) + fn() + "\n" + mt.group(2), text)
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="fail if a file differs from the generated tables")
    args = ap.parse_args(argv)
    stale = []
    for path, names in ((README, README_BLOCKS), (RUNNING, RUNNING_BLOCKS), (INTRO, INTRO_BLOCKS)):
        old = path.read_text()
        try:
            new = render(old, names, path.name)
        except ValueError as exc:
            print(f"readme_tables: {exc}", file=sys.stderr)
            return 2
        if new != old:
            stale.append(path)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print(f"readme_tables: {', '.join(p.name for p in stale)}: the generated tables are stale; run "
              f"`python scripts/readme_tables.py`", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
