"""Accuracy tables: the eval split, the census against the learned readouts, nuisances and
occlusion, the native pathway, the held-out labeled pairs and the reproduction.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from .common import (
    CENSUS,
    EXPORT_DEFAULT,
    NATIVE_DEFAULT,
    READOUTS,
    Json,
    Sources,
    ep_b1,
    f2,
    f3,
    footer,
    fps3,
    mega,
    metrics_of,
    pct,
    signed,
    table,
)

# ---------------------------------------------------------------- accuracy


def accuracy_headline(src: Sources) -> str:
    rows = []
    for profile in ("w160", "w320"):
        ev, na = src.metrics(f"eval_{profile}"), src.metrics(f"native_{profile}")
        sgbm = metrics_of(ev["mean"]["sgbm"])
        census = metrics_of(ev["mean"][f"int8_{CENSUS}"])
        readouts = (
            ("`bino run`'s default, no encoder", CENSUS, ev),
            ("export pathway, learned", EXPORT_DEFAULT, ev),
            ("native pathway, the board's learned preset", NATIVE_DEFAULT, na),
        )
        for label, readout, run in readouts:
            ours = metrics_of(run["mean"][f"int8_{readout}"])
            wins = [k for k in ("epe", "bad1tok", "bad2") if ours[k] < sgbm[k]]
            rows.append(
                [
                    f"{profile} ({ev['pairs']} eval pairs)",
                    f"int8 `{readout}` ({label})",
                    f3(ours["epe"]),
                    f2(ours["bad1tok"]),
                    f2(ours["bad2"]),
                    f"{ours['epe'] / census['epe']:.2f}x",
                    ", ".join(wins) if wins else "none",
                ]
            )
        rows.append(
            [
                f"{profile} ({ev['pairs']} eval pairs)",
                "StereoSGBM (OpenCV, same run)",
                f3(sgbm["epe"]),
                f2(sgbm["bad1tok"]),
                f2(sgbm["bad2"]),
                f"{sgbm['epe'] / census['epe']:.2f}x",
                "",
            ]
        )
    header = ["profile", "readout", "epe px", "bad1tok %", "bad2 %", "epe / census"]
    header += ["better than StereoSGBM on"]
    return table(header, rows, [False, False] + [True] * 4 + [False]) + "\n\n" + footer(src)


def eval_unrefined(src: Sources) -> str:
    evs = {p: src.metrics(f"eval_{p}") for p in ("w160", "w320")}
    rows = []
    for precision in ("f32", "int8"):
        for r in READOUTS:
            row = [f"{precision} `{r}`"]
            for p in ("w160", "w320"):
                e = evs[p]["mean"][f"{precision}_{r}"]
                m = metrics_of(e)
                row += [
                    f3(m["epe"]),
                    f2(m["bad1tok"]),
                    f2(m["bad2"]),
                    f"{e['lr_keep']:.1f}",
                    f3(e["gt_lr_epe"]),
                ]
            rows.append(row)
    row = ["StereoSGBM"]
    for p in ("w160", "w320"):
        m = metrics_of(evs[p]["mean"]["sgbm"])
        row += [f3(m["epe"]), f2(m["bad1tok"]), f2(m["bad2"]), f"density {m['density']:.1f}", "-"]
    rows.append(row)
    header = ["readout"]
    for p in ("w160", "w320"):
        header += [f"{p} epe", "bad1tok", "bad2", "LRkeep", "GT+LR epe"]
    return table(header, rows) + "\n\n" + footer(src)


def eval_refined(src: Sources) -> str:
    evs = {p: src.metrics(f"eval_{p}") for p in ("w160", "w320")}
    rows = []
    for precision in ("int8", "f32"):
        for r in READOUTS:
            row = [f"{precision} `{r}+ref`"]
            for p in ("w160", "w320"):
                raw = metrics_of(evs[p]["mean"][f"{precision}_{r}"])
                m = metrics_of(evs[p]["mean"][f"{precision}_{r}+ref"])
                change = 100.0 * (m["epe"] / raw["epe"] - 1.0)
                row += [f3(m["epe"]), f"{change:+.0f} %", f2(m["bad1tok"]), f2(m["bad2"])]
            rows.append(row)
    row = ["StereoSGBM"]
    for p in ("w160", "w320"):
        m = metrics_of(evs[p]["mean"]["sgbm"])
        row += [f3(m["epe"]), "", f2(m["bad1tok"]), f2(m["bad2"])]
    rows.append(row)
    header = ["readout"]
    for p in ("w160", "w320"):
        header += [f"{p} epe", "vs unrefined", "bad1tok", "bad2"]
    return table(header, rows) + "\n\n" + footer(src)


def probe_and_head(src: Sources) -> str:
    probe, rnd = src.metrics("probe_trained"), src.metrics("probe_random")
    head = src.metrics("head_eval_w160")
    cmp = src.metrics("int8_compare_w160")["mean"]
    rows = [
        ("no-linkage probe, trained encoder (float)", probe),
        ("no-linkage probe, the same architecture at random init (float)", rnd),
        ("shared head (float)", head["head"]),
        ("shared head with its own left-right check and fill, `head+lr` (float)", head["head+lr"]),
        ("no-linkage probe, int8 engine", cmp["int8"]),
        ("shared head, int8 engine", cmp["head"]["int8"]),
        (f"StereoSGBM (density {head['sgbm']['density']:.1f} %)", head["sgbm"]),
    ]
    body = [[name, f3(m["epe"]), f2(m["bad1tok"]), f2(m["bad2"])] for name, m in rows]
    return (
        table(["readout (w160, eval split)", "epe px", "bad1tok %", "bad2 %"], body)
        + "\n\n"
        + footer(src)
    )


def int8_vs_float(src: Sources) -> str:
    c = src.metrics("int8_compare_w160")
    m = c["mean"]
    shown = {
        "descriptor_cosine": ("descriptor cosine", lambda v: f"{v:.5f}"),
        "wta_agreement_pct": ("token WTA agreement", lambda v: pct(v, 2)),
        "epe_change_pct": ("no-linkage epe change, int8 over float", lambda v: f"{v:+.2f} %"),
    }
    rows = []
    for t in c["targets"]:
        label, fmt = shown.get(t["name"], (t["name"], lambda v: f"{v:g}"))
        rows.append([label, t["target"], fmt(t["value"]), "met" if t["pass"] else "**missed**"])
    rows += [
        [
            "shared head: epe change, int8 over float",
            "-",
            f"{m['head']['epe_change_pct']:+.2f} %",
            "",
        ],
        ["shared head: logit cosine", "-", f"{m['head']['logit_cosine']:.4f}", ""],
        ["native pathway: pair token cosine", "-", f"{m['native']['pair_token_cosine']:.5f}", ""],
        ["native head: logit cosine", "-", f"{m['native']['head']['logit_cosine']:.4f}", ""],
        [
            "native head: epe change, int8 over float",
            "-",
            f"{m['native']['head']['epe_change_pct']:+.2f} %",
            "",
        ],
        [
            "WTA flips: int8 winner's float-cosine loss / median best-to-second gap",
            "-",
            f"{m['wta_flip_loss']:.5f} / {m['wta_top2_gap']:.5f}",
            "",
        ],
    ]
    return (
        table(
            ["measure (w160, eval split)", "target", "measured", "state"],
            rows,
            [False, False, True, False],
        )
        + "\n\n"
        + footer(src)
    )


def pck_benchmark(src: Sources) -> str:
    t, r = src.metrics("benchmark_trained"), src.metrics("benchmark_random")
    rows = []
    for level in ("easy", "hard"):
        for name, d in (("trained", t), ("random init", r)):
            rows.append(
                [f"{level.upper()}, {name}"] + [f"{d[f'{level}_pck{k}']:.1f}" for k in (0, 1, 2)]
            )
    return table(["split, encoder", "PCK@0 %", "PCK@1 %", "PCK@2 %"], rows) + "\n\n" + footer(src)


# ---------------------------------------------------------------- robustness


def nuisance(profile: str, run: str = "eval_nuisance") -> Callable[[Sources], str]:
    """The nuisance table of `{run}_{profile}` (the export or the native pathway's run)."""

    def render(src: Sources) -> str:
        ev = src.metrics(f"{run}_{profile}")
        names = list(ev["nuisances"])
        # The census reads pixels only, the same on either pathway: the native table shows the
        # export run's census row, the baseline either pathway's learned readout must beat.
        census = f"int8_{CENSUS}"
        baseline = src.metrics(f"eval_nuisance_{profile}") if census not in ev["mean"] else ev
        keys = [census] if baseline is not ev else []
        rows = []
        for key in keys + [k for k in ev["mean"] if k != "sgbm_large"]:
            got = baseline if key == census else ev
            label = "StereoSGBM" if key == "sgbm" else key.replace("_", " ", 1)
            row = [label, ep_b1(metrics_of(got["mean"][key]))]
            for name in names:
                nu = got["nuisances"][name]
                rise = nu["epe_rise"][key]
                star = " \\*" if nu.get("rise_below_sgbm", {}).get(key) else ""
                row.append(f"{ep_b1(metrics_of(nu['mean'][key]))} ({signed(rise)}{star})")
            rows.append(row)
        header = ["readout", "clean"] + names
        note = (
            f"{profile}, {ev['pairs']} eval pairs, epe px / bad1tok %, "
            "then the epe rise over clean; "
            "`*`: the rise is below StereoSGBM's."
        )
        return note + "\n\n" + table(header, rows, [False] * (len(header))) + "\n\n" + footer(src)

    return render


def occlusion_export(src: Sources) -> str:
    ev = src.metrics("occlusion_w160")
    summary = ev["occlusion"]["summary"]
    rows = []
    for key, s in summary.items():
        large = ev["mean"]["sgbm_large"] if key == "StereoSGBM" else ev["mean"][key]["large"]
        last = s["severities"][-1]
        label = key if key == "StereoSGBM" else key.replace("_", " ", 1)
        rows.append(
            [
                label,
                ep_b1(large),
                ep_b1(s["clean"]),
                ep_b1(last),
                f"{f3(s['auc_epe'])} / {f2(s['auc_bad1tok'])}",
                f"{signed(s['delta_epe'])} / {signed(s['delta_bad1tok'], 2)}",
            ]
        )
    top = ev["occlusion"]["severities"][-1]
    header = ["readout (w160)", "large-disparity subset", "clean", f"Occ{top}", "OccAUC", f"Δ{top}"]
    return table(header, rows, [False] * 6) + "\n\n" + footer(src)


# ---------------------------------------------------------------- native pathway


def native_vs_export(src: Sources) -> str:
    ex160, na160 = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_w320")
    exo, nao = src.metrics("occlusion_w160"), src.metrics("native_occlusion_w160")
    rows = []
    # Each head readout on both pathways, then each pathway's default (its head fused with its
    # second opinion: the descriptor SGM, the census SGM).
    pairs = [(f"int8 `{r}`", f"int8_{r}", f"int8_{r}") for r in ("head", "head+lr", "head+lr+ref")]
    pairs.append(
        (
            f"each learned default: int8 `{EXPORT_DEFAULT}` / `{NATIVE_DEFAULT}`",
            f"int8_{EXPORT_DEFAULT}",
            f"int8_{NATIVE_DEFAULT}",
        )
    )
    for label, k, kn in pairs:
        eo, no = exo["occlusion"]["summary"][k], nao["occlusion"]["summary"][kn]
        rows.append(
            [
                label,
                ep_b1(metrics_of(ex160["mean"][k])),
                ep_b1(metrics_of(na160["mean"][kn])),
                ep_b1(exo["mean"][k]["large"]),
                ep_b1(nao["mean"][kn]["large"]),
                f"{signed(eo['delta_epe'])} / {signed(eo['delta_bad1tok'], 2)}",
                f"{signed(no['delta_epe'])} / {signed(no['delta_bad1tok'], 2)}",
                ep_b1(metrics_of(ex320["mean"][k])),
                ep_b1(metrics_of(na320["mean"][kn])),
            ]
        )
    # The census reads pixels only: one row, the same on both pathways (the export runs').
    c = f"int8_{CENSUS}"
    co = exo["occlusion"]["summary"][c]
    rows.append(
        [
            f"int8 `{CENSUS}` (no encoder, either pathway)",
            ep_b1(metrics_of(ex160["mean"][c])),
            ep_b1(metrics_of(na160["mean"][c])),
            ep_b1(exo["mean"][c]["large"]),
            "",
            f"{signed(co['delta_epe'])} / {signed(co['delta_bad1tok'], 2)}",
            "",
            ep_b1(metrics_of(ex320["mean"][c])),
            ep_b1(metrics_of(na320["mean"][c])),
        ]
    )
    so = exo["occlusion"]["summary"]["StereoSGBM"]
    rows.append(
        [
            "StereoSGBM",
            ep_b1(metrics_of(ex160["mean"]["sgbm"])),
            "",
            ep_b1(exo["mean"]["sgbm_large"]),
            "",
            f"{signed(so['delta_epe'])} / {signed(so['delta_bad1tok'], 2)}",
            "",
            ep_b1(metrics_of(ex320["mean"]["sgbm"])),
            "",
        ]
    )
    top = exo["occlusion"]["severities"][-1]
    header = [
        "readout",
        "export w160",
        "native w160",
        "export large subset",
        "native large subset",
        f"export Δ{top}",
        f"native Δ{top}",
        "export w320",
        "native w320",
    ]
    note = "epe px / bad1tok %, eval split, the same blob for both pathways."
    return note + "\n\n" + table(header, rows, [False] * 9) + "\n\n" + footer(src)


def native_float(src: Sources) -> str:
    ex160, na160 = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_f32_w320")
    rows = []
    for r in ("head", "head+lr", "head+lr+ref"):
        k = f"f32_{r}"
        rows.append(
            [
                f"f32 `{r}`",
                ep_b1(metrics_of(ex160["mean"][k])),
                ep_b1(metrics_of(na160["mean"][k])),
                ep_b1(metrics_of(ex320["mean"][k])),
                ep_b1(metrics_of(na320["mean"][k])),
            ]
        )
    header = ["readout", "export w160", "native w160", "export w320", "native w320"]
    return table(header, rows, [False] * 5) + "\n\n" + footer(src)


NATIVE_CHECKS = {
    "none": "no check",
    "mirrored": "second encoder pass on the mirrored pair",
    "diagonal": "right view from the logits' diagonal (one pass; shipped)",
    "confident0.5": "softmax peak >= 0.5",
}
FOLDER_TITLES = {
    "heldout": "held-out labeled",
    "synth": "synthetic",
    "synthreal": "synthetic, real textures",
}


def heldout_labeled(src: Sources) -> str:
    """The held-out labeled train pairs (validation): per pair, the readouts every recipe was
    chosen with against StereoSGBM, and how far the worst pair is from StereoSGBM's epe."""
    evs = {w: src.metrics(f"heldout_w{w}") for w in (160, 320)}
    natives = {w: src.metrics(f"native_heldout_w{w}") for w in (160, 320)}
    readouts = [CENSUS, "sgm+lr+ref", "head+lr+ref", "fuse+lr+ref", EXPORT_DEFAULT]
    rows = []
    pairs = [p["pair_id"] for p in evs[160]["per_pair"]]
    for i, pair in enumerate(pairs + ["mean"]):
        row = [f"`{pair}`" if pair != "mean" else "mean"]
        for w in (160, 320):
            ev = evs[w]
            got = ev["mean"] if pair == "mean" else ev["per_pair"][i]["readouts"]
            for r in readouts:
                row.append(ep_b1(metrics_of(got[f"int8_{r}"])))
            na = natives[w]
            native = na["mean"] if pair == "mean" else na["per_pair"][i]["readouts"]
            row.append(ep_b1(metrics_of(native[f"int8_{NATIVE_DEFAULT}"])))
            sgbm = metrics_of(got["sgbm"])
            census = metrics_of(got[f"int8_{CENSUS}"])
            learned = min(
                metrics_of(got[f"int8_{EXPORT_DEFAULT}"])["epe"],
                metrics_of(native[f"int8_{NATIVE_DEFAULT}"])["epe"],
            )
            row += [ep_b1(sgbm), f"{learned / census['epe']:.2f}"]
        rows.append(row)
    header = ["pair"]
    for w in (160, 320):
        header += [f"w{w} int8 `{r}`" for r in readouts]
        header += [f"w{w} native `{NATIVE_DEFAULT}` (the board's)"]
        header += [f"w{w} StereoSGBM", "best learned / census epe"]
    note = (
        "epe px / bad1tok %, int8, the held-out labeled train pairs no head was trained on "
        "(`bino_train.labeled.LABELED_HOLDOUT`: four MiddEval3-Q pairs and Middlebury 2006 "
        "Monopoly, resized by `bino_train.labeled_folder`), StereoSGBM in the same run; "
        "`scripts/measure_tables.sh heldout_w160 heldout_w320` (the native pathway's run: "
        "`native_heldout_w160`, `native_heldout_w320`). The last column: the better of the two "
        "learned defaults over `census+lr+ref`, below 1 where learning pays."
    )
    return note + "\n\n" + table(header, rows, [False] * len(header)) + "\n\n" + footer(src)


def mean_over(run: Json, key: str, pairs: Sequence[str]) -> Json:
    """The mean epe and bad1tok of `key` over `pairs` of an eval run's `per_pair`."""
    got = {p["pair_id"]: metrics_of(p["readouts"][key]) for p in run["per_pair"]}
    missing = [p for p in pairs if p not in got]
    if missing:
        raise SystemExit(f"{key}: no score for {', '.join(missing)}")
    return {m: sum(got[p][m] for p in pairs) / len(pairs) for m in ("epe", "bad1tok")}


REPRO = "train/checkpoints/repro_p7_short_blur/metrics"
"""The from-scratch reproduction's measurements (its own blob, the same commands)."""


def reproduction(src: Sources) -> str:
    """The weights `scripts/train_weights.sh` reproduced from scratch against the shipped ones:
    the encoder's probe and, int8, each pathway's default readout on the eval split and the
    held-out labeled pairs, StereoSGBM in the same runs."""

    def both(run: str, key: str) -> list[str]:
        """The shipped and the reproduced blob's mean of `key` in `run`, over the pairs the
        reproduction scored (the held-out set grew after it)."""
        shipped, repro = src.metrics(run), src.json(f"{REPRO}/{run}.json")
        if "per_pair" not in repro:
            got = (shipped["mean"][key], repro["mean"][key])
            return [ep_b1(metrics_of(g)) for g in got]
        pairs = [p["pair_id"] for p in repro["per_pair"]]
        return [ep_b1(mean_over(r, key, pairs)) for r in (shipped, repro)]

    probes = (src.metrics("probe_trained"), src.json(f"{REPRO}/probe_trained.json"))
    rows = [["no-linkage probe, eval w160 (float)", *(ep_b1(p) for p in probes)]]
    for label, prefix in (("eval split", "eval"), ("held-out labeled", "heldout")):
        for w in (160, 320):
            run, default = f"{prefix}_w{w}", EXPORT_DEFAULT
            rows.append([f"{label} w{w}, `{default}`", *both(run, f"int8_{default}")])
            if prefix == "heldout":
                native = both(f"native_{run}", f"int8_{NATIVE_DEFAULT}")
                rows.append([f"{label} w{w}, native `{NATIVE_DEFAULT}`", *native])
            rows.append([f"{label} w{w}, StereoSGBM", *both(run, "sgbm")])
    header = ["readout (int8 unless said)", "shipped weights", "reproduced from scratch"]
    note = "epe px / bad1tok %, each set scored by the same command on both blobs."
    return note + "\n\n" + table(header, rows, [False] * 3) + "\n\n" + footer(src)


def native_checks(src: Sources) -> str:
    """The native head's left-right checks on the validation folders (float, unrefined)."""
    data = src.json("train/checkpoints/metrics/native_checks.json")
    folders = list(data["folders"].items())
    rows = []
    for check, label in NATIVE_CHECKS.items():
        row = [label]
        for _, f in folders:
            m = f[check]["mean"]
            row.append(f"{ep_b1(m)} ({m['kept']:.0f} %)")
        rows.append(row)
    header = ["check"]
    for path, f in folders:
        kind = Path(path).name.rstrip("0123456789")
        header.append(f"{FOLDER_TITLES.get(kind, kind)} w{f['width']}")
    return table(header, rows, [False] * len(header)) + "\n\n" + footer(src)


def census_vs_learned(src: Sources) -> str:
    """One sentence: where `census+lr+ref` is more accurate than both learned defaults (epe),
    where a learned one is, and what each costs on the board's M55 per 48x160 band pair."""
    # Each set's name, then the widths where the census or a learned readout has the lower epe.
    wins: dict[str, dict[bool, list[str]]] = {}

    def judge(name: str, width: str, census: float, learned: float) -> None:
        wins.setdefault(name, {True: [], False: []})[census <= learned].append(width)

    def learned_epe(export: Json, native: Json) -> float:
        return min(
            metrics_of(export[f"int8_{EXPORT_DEFAULT}"])["epe"],
            metrics_of(native[f"int8_{NATIVE_DEFAULT}"])["epe"],
        )

    for name, run in (("the eval split", "w"), ("the held-out real labeled pairs", "heldout_w")):
        for w in (160, 320):
            ex = src.metrics(f"eval_w{w}" if run == "w" else f"heldout_w{w}")
            na = src.metrics(f"native_w{w}" if run == "w" else f"native_heldout_w{w}")
            census = metrics_of(ex["mean"][f"int8_{CENSUS}"])["epe"]
            judge(name, f"w{w}", census, learned_epe(ex["mean"], na["mean"]))
    for w in (160, 320):
        ev, na = src.metrics(f"eval_nuisance_w{w}"), src.metrics(f"native_nuisance_w{w}")
        for name in ev["nuisances"]:
            means = ev["nuisances"][name]["mean"], na["nuisances"][name]["mean"]
            census = metrics_of(means[0][f"int8_{CENSUS}"])["epe"]
            judge(f"{name} nuisance", f"w{w}", census, learned_epe(*means))
    occ = src.metrics("occlusion_w160")["occlusion"]["summary"]
    native_occ = src.metrics("native_occlusion_w160")["occlusion"]["summary"]
    judge(
        "the one-view occlusion benchmark (OccAUC)",
        "w160",
        occ[f"int8_{CENSUS}"]["auc_epe"],
        min(occ[f"int8_{EXPORT_DEFAULT}"]["auc_epe"], native_occ[f"int8_{NATIVE_DEFAULT}"]["auc_epe"]),
    )

    def sets(census_better: bool) -> str:
        parts = [f"{name} ({', '.join(w[census_better])})" for name, w in wins.items() if w[census_better]]
        return ", ".join(parts) if parts else "none of them"

    presets = src.budget()["presets"]["frames"]

    def on_frame(preset: str) -> Json:
        return next(
            p
            for p in presets
            if p["core"] == "m55" and p["preset"] == preset and p["frame"] == {"width": 160, "height": 120}
        )

    fast, learned = on_frame("fast"), on_frame("learned")

    def how(p: Json) -> str:
        return "counted on the same frame" if p["source"] == "measured_frame" else "scaled from its band pair"

    return (
        f"`{CENSUS}` has a lower epe than both learned readouts (`{EXPORT_DEFAULT}`, "
        f"`{NATIVE_DEFAULT}`) on {sets(True)}; a learned readout is more accurate on "
        f"{sets(False)}. On the board's Cortex-M55 a 160x120 frame costs "
        f"{mega(fast['instructions'])} instructions with the census, counted on the firmware's "
        f"whole frame ({fps3(fast['frames_per_s_ipc1'])} frames/s at "
        f"{fast['clock_mhz']:.0f} MHz, IPC 1), against {mega(learned['instructions'])} "
        f"({fps3(learned['frames_per_s_ipc1'])} frames/s, {how(learned)}) for the "
        f"learned native preset.\n\n" + footer(src)
    )
