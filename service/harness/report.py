"""Markdown rendering of a results dictionary (tables, figure links, labels)."""

from __future__ import annotations

from typing import Any

from service.harness.methods import METHOD_LABELS


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _bytes(b: float | None) -> str:
    if b is None:
        return "—"
    for unit, scale in (("MB", 1e6), ("kB", 1e3)):
        if b >= scale:
            return f"{b / scale:.1f} {unit}"
    return f"{b:.0f} B"


def _p(x: float) -> str:
    return f"{100 * x:.1f}%"


def _params(p: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in p.items() if k not in ("dtype", "trainer"))


def header(results: dict[str, Any]) -> str:
    ds, ctx, cfg = results["dataset"], results["context"], results["config"]
    lines = ["# gridplace — paper experiments", ""]
    if ds["synthetic"]:
        lines += ["> **SYNTHETIC DATA** — " + ds["label"], ""]
    lines += [
        f"- **Dataset:** {ds['label']} (N={ds['N']}, queries={ds['n_queries']}, d={ds['d']})",
        f"- **Preprocessing:** `{ds['preprocessing']}`",
        (
            f"- **Budget:** `{cfg['preset']}`; sweep trainer `{cfg['trainer']}`, "
            f"storage dtype `{cfg['dtype']}`, seed {cfg['seed']}"
        ),
        (
            f"- **Machine:** {ctx['machine']['cores']} usable cores ({ctx['machine']['processor']}, "
            f"{ctx['machine']['platform']})"
            + (
                f"; torch trainer on {ctx['machine']['torch_threads']} thread(s)"
                if ctx["machine"].get("torch_threads")
                else ""
            )
        ),
        (
            f"- **Date:** {ctx['date']}; gridplace commit `{ctx['git_commit']}`; "
            f"total {results['elapsed_seconds'] / 60:.1f} min"
        ),
        f"- **Command:** `{ctx['command']}`",
        (
            "- Storage in *paper bytes* is the paper's formula (float64 weights, 1 bit per column "
            "mask); *actual bytes* are the stored tensors at the storage dtype."
        ),
        "",
    ]
    return "\n".join(lines)


def best_precision_table(res: dict[str, Any]) -> str:
    """Best precision over the whole grid per method and N: the ceiling each target meets."""
    sizes = res["sizes"]
    conds = dict.fromkeys((t["condition"], t["tolerance"]) for t in res["targets"])
    rows = []
    for cond, tol in conds:
        for method in dict.fromkeys(p["method"] for p in res["points"]):
            best = []
            for n in sizes:
                vals = [p[cond][str(tol)] for p in res["points"]
                        if p["method"] == method and p["N"] == n and "error" not in p]  # fmt: skip
                best.append(_p(max(vals)) if vals else "—")
            rows.append([f"{cond} ±{tol}", METHOD_LABELS.get(method, method), *best])
        if cond == "cross":
            rows.append([f"{cond} ±{tol}", "chance (uniform guess)",
                         *(_p(min(1.0, (2 * tol + 1) / n)) for n in sizes)])  # fmt: skip
    head = ["condition", "best precision over the grid", *(f"N={n}" for n in sizes)]
    return _table(head, rows)


def storage_section(res: dict[str, Any], fig: str | None) -> str:
    out = ["## 1. Storage scaling (paper Fig. 7 / Table I)", "",
           (f"Sub-routes of N = {res['sizes']} frames ({res.get('sub_routes', 'route prefixes')}); "
            "for each target, the smallest storage over the same (ρ, k) grid per method; fit "
            "storage = c·N^a over the sizes where the target was reached (a from two sizes "
            "is indicative only), and the paper's own form, storage in MB = N^a with no "
            "prefactor (least squares in MB), whose exponent also absorbs the scale: exactly "
            "linear storage gets a ≈ 0.5 there."), "", best_precision_table(res), ""]  # fmt: skip
    for tgt in res["targets"]:
        cond = "identical (train = test)" if tgt["condition"] == "identical" else "cross-condition"
        out += [f"**{cond}, precision ≥ {_p(tgt['target'])} within ±{tgt['tolerance']} frames**",
                ""]  # fmt: skip
        rows = []
        for method, m in tgt["methods"].items():
            fit, fit_a, form = m.get("fit_paper"), m.get("fit_actual"), m.get("fit_paper_form")
            last = m["best"][-1] if m["best"] else None
            rows.append([
                METHOD_LABELS.get(method, method),
                f"{fit['a']:.2f} (r²={fit['r2']:.2f}, {fit['n_points']} sizes)" if fit else "—",
                f"{fit_a['a']:.2f}" if fit_a else "—",
                f"{form['a']:.2f}" if form else "—",
                ", ".join(str(b["N"]) for b in m["best"]) or "never",
                f"{_bytes(last['paper_bytes'])} / {_bytes(last['actual_bytes'])} at N={last['N']}"
                if last else "—",
                _params(last["params"]) if last else "—",
            ])  # fmt: skip
        out += [
            _table(
                [
                    "method",
                    "a (paper bytes)",
                    "a (actual)",
                    "a, paper's form MB = N^a",
                    "target reached at N",
                    "storage paper / actual (largest N)",
                    "setting there",
                ],
                rows,
            ),
            "",
        ]
    if fig:
        out += [f"![storage scaling]({fig})", ""]
    return "\n".join(out)


def timing_section(res: dict[str, Any], fig: str | None) -> str:
    sizes = res["sizes"]
    keys = list(dict.fromkeys((r["method"], r["trainer"]) for r in res["rows"]))
    rows = []
    for key in keys:
        by_n = {r["N"]: r for r in res["rows"] if (r["method"], r["trainer"]) == key}
        fit = res["fits"].get(f"{key[0]}/{key[1]}")
        rows.append([f"{key[0]} / {key[1]}",
                     *(f"{by_n[n]['train_seconds']:.2f}" if n in by_n else "—" for n in sizes),
                     f"{fit['a']:.2f}" if fit else "—",
                     *(f"{by_n[n]['query_us_per_descriptor_batch']:.0f} / "
                       f"{by_n[n]['query_us_single']:.0f}" if n in by_n else "—"
                       for n in sizes[-1:])])  # fmt: skip
    head = ["method / trainer", *(f"train s N={n}" for n in sizes), "a (time ∝ N^a)",
            f"query µs batch / single, N={sizes[-1]}"]  # fmt: skip
    out = ["## 2. Training and query time vs N (paper Table II)", "",
           (f"Same machine, same run; k and ρ as in the JSON `params`; fastest of the repeated fits "
            "(see `repeats` in the JSON). The slow trainers "
           f"({', '.join(res['slow_trainers'])}) stop at N ≤ {res['slow_trainer_max_n']} in "
           "this budget."), "",
           _table(head, rows), ""]  # fmt: skip
    if fig:
        out += [f"![timing]({fig})", ""]
    return "\n".join(out)


def patterns_section(res: dict[str, Any], fig: str | None) -> str:
    tol = str(res["cross_tolerance"])
    rows = [[METHOD_LABELS.get(r["method"], r["method"]), str(r["k"]), str(r["periods"]),
             _p(r["identical"]["0"]), _p(r["cross"]["0"]), _p(r["cross"][tol]),
             _bytes(r["paper_bytes"]), _bytes(r["actual_bytes"])] for r in res["rows"]]  # fmt: skip
    out = ["## 3. Precision vs number of patterns k", "", f"N = {res['N']}.", "",
           _table(["method", "k", "periods", "identical ±0", "cross ±0", f"cross ±{tol}",
                   "paper bytes", "actual bytes"], rows), ""]  # fmt: skip
    if fig:
        out += [f"![patterns]({fig})", ""]
    return "\n".join(out)


def chunking_section(res: dict[str, Any], fig: str | None) -> str:
    tols = res["tolerances"]
    rows = []
    for name, m in res["models"].items():
        for cond in res["conditions"]:
            c = m[cond]
            rows.append([name, cond, *(_p(c["precision"][str(t)]) for t in tols),
                         _p(c["chunk_accuracy"]) if "chunk_accuracy" in c else "—",
                         f"{m['train_seconds']:.1f}", f"{c['query_us_per_descriptor']:.0f}",
                         _bytes(m["paper_bytes"]), _bytes(m["actual_bytes"])])  # fmt: skip
    ds = res["dataset"]
    out = ["## 4. Chunking at scale", "",
           (f"> **SYNTHETIC route** ({ds['label']}); no real route of ≥ 89,000 frames is "
            f"available. {res['n_queries_scored']} queries per condition scored "
            f"({res['query_selection']}); *identical* = the reference frames themselves, "
            "*noisy* = the synthetic second traversal."), "",
           _table(["model", "queries", *(f"±{t}" for t in tols), "chunk acc.", "train s",
                   "µs/query", "paper bytes", "actual bytes"], rows), ""]  # fmt: skip
    if fig:
        out += [f"![chunking]({fig})", ""]
    return "\n".join(out)


def retrieval_section(res: dict[str, Any], fig: str | None) -> str:
    tols = res["tolerances"]
    rows = []
    for r in res["rows"]:
        if "error" in r:
            rows.append([r["method"], "error: " + r["error"], *[""] * (6 + 2 * len(tols))])
            continue
        rows.append([r["label"], _bytes(r["paper_bytes"]), _bytes(r["actual_bytes"]),
                     f"{r['train_seconds']:.1f}",
                     f"{r['cross']['query_us_per_descriptor']:.0f} / {r['query_us_single']:.0f}",
                     *(_p(r["identical"]["precision"][str(t)]) for t in tols),
                     *(_p(r["cross"]["precision"][str(t)]) for t in tols),
                     f"{r['cross']['pr']['average_precision']:.3f}",
                     _p(r["cross"]["pr"]["recall_at_100_precision"])])  # fmt: skip
    note = "" if res["faiss"] else " faiss is not installed, so PQ is absent."
    out = ["## 5. Against retrieval", "",
           (f"N = {res['N']}. Precision within ±t frames; AP and recall at 100 % precision from "
           f"rejecting low-confidence cross-condition queries.{note}"), "",
           _table(["method", "paper bytes", "actual bytes", "train s", "µs/query batch / single",
                   *(f"ident ±{t}" for t in tols), *(f"cross ±{t}" for t in tols),
                   "cross AP", "cross R@100%P"], rows), ""]  # fmt: skip
    if fig:
        out += [f"![retrieval]({fig})", ""]
    return "\n".join(out)


SECTIONS = {
    "storage": storage_section,
    "timing": timing_section,
    "patterns": patterns_section,
    "chunking": chunking_section,
    "retrieval": retrieval_section,
}


def render(results: dict[str, Any], figure_prefix: str = "") -> str:
    """The whole report; figures are linked as ``figure_prefix + file name``."""
    parts = [header(results)]
    for name, section in SECTIONS.items():
        if name in results["experiments"]:
            fig = results["figures"].get(name)
            parts.append(
                section(results["experiments"][name], figure_prefix + fig if fig else None)
            )
    return "\n".join(parts)
