"""Firmware, board and weights tables: the QEMU runs, `bino budget`, the boards' regions, the
frames and the shipped files.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .common import (
    CENSUS,
    EXPORT_DEFAULT,
    MANIFEST,
    MEASURED,
    NATIVE_DEFAULT,
    Json,
    Sources,
    census_instructions,
    ep_b1,
    footer,
    fps3,
    mega,
    metrics_of,
    n,
    pct,
    table,
)

# ---------------------------------------------------------------- firmware


CORES = ("m55", "m7")


def core_label(c: Json) -> str:
    return f"Cortex-{c['cpu'].split('-')[1].upper()} ({c['board']})"


def board_headline(src: Sources) -> str:
    """Per core, the board's learned preset (the native pathway) and the export pathway: instructions of
    a 48x160 band pair, their time at IPC 1 and under the cycle model, the firmware's arena
    (one serves both runs) and blob."""
    rows = []
    for core in CORES:
        c = src.core(core)
        cm = c["cycle_model"]
        runs = (
            ("native (the board's learned preset)", c["native_band_pair_instructions"], cm["native_band_pair_modelled_ms"]),
            ("export", c["band_pair_instructions"], cm["band_pair_modelled_ms"]),
        )
        for pathway, ins, modelled_ms in runs:
            rows.append(
                [
                    f"{core_label(c)} at {c['clock_mhz']:.0f} MHz",
                    pathway,
                    mega(ins),
                    f"{ins / (c['clock_mhz'] * 1e3) / 1000:.2f} s",
                    f"{modelled_ms / 1000:.2f} s",
                    f"{n(c['arena_static_bytes'])} B",
                    f"{n(c['weights_flash_bytes'])} B",
                    "yes" if c["outputs_bit_identical"] else "**no**",
                ]
            )
    header = [
        "core (QEMU)",
        "pathway",
        "instructions per 48x160 band pair",
        "time at IPC 1",
        "cycle model",
        "arena",
        "weights flash",
        "bit-identical to the host",
    ]
    return table(header, rows) + "\n\n" + footer(src)


def board_pathways(src: Sources) -> str:
    """The board's readouts side by side: cost of a checked 48x160 band pair on each core and the
    accuracy of the refined readout on the eval split at w160 (the board's 160-px bands) and
    w320: the census alone (no encoder; its instructions the measured native run's rows, census
    SGM and refinement stages) and each pathway's learned default (the head fused with the
    descriptor SGM, or with the census SGM)."""
    ex, na = src.metrics("eval_w160"), src.metrics("native_w160")
    ex320, na320 = src.metrics("eval_w320"), src.metrics("native_w320")
    pathways = (
        (
            "census, no encoder (`bino run`'s default): census SGM, its check, refinement",
            census_instructions,
            (ex, ex320),
            CENSUS,
        ),
        (
            "export: encode (L, L) and (R, R), SGM, census SGM, head, mirrored head",
            lambda c: c["band_pair_instructions"],
            (ex, ex320),
            EXPORT_DEFAULT,
        ),
        (
            "native (the board's learned preset): one encode on (L, R), native head, right view from its logits, census SGM",
            lambda c: c["native_band_pair_instructions"],
            (na, na320),
            NATIVE_DEFAULT,
        ),
    )
    rows = []
    for label, instructions, metrics, readout in pathways:
        row = [label, f"int8 `{readout}`"]
        row += [ep_b1(metrics_of(m["mean"][f"int8_{readout}"])) for m in metrics]
        for core in CORES:
            c = src.core(core)
            ins = instructions(c)
            row.append(f"{mega(ins)} ({ins / (c['clock_mhz'] * 1e6):.2f} s)")
        rows.append(row)
    header = ["readout, left-right check included", "readout", "eval w160 epe / bad1tok", "eval w320"]
    header += [f"{core.upper()} instructions (s at IPC 1)" for core in CORES]
    return table(header, rows) + "\n\n" + footer(src)


def e7_arena(run: Json) -> str:
    """The learned preset's arena on the E7's 320x240 frame, static / used, or a dash for a core
    that did not run it."""
    f = run.get("frame320")
    return f"{n(f['arena_bytes'])} / {n(f['arena_used'])} B" if f else "- (not run)"


def fw_memory(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    runs = {k: src.run(k) for k in CORES}
    spec: list[tuple[str, Callable[[str], str]]] = [
        (
            "weights flash (`.weights`: the blob, both heads)",
            lambda k: f"{n(cs[k]['weights_flash_bytes'])} B",
        ),
        (
            "code flash (`.vector_table .text .rodata .data`)",
            lambda k: f"{n(cs[k]['code_flash_bytes'])} B",
        ),
        (
            "arena, static / high-water, export pathway",
            lambda k: f"{n(cs[k]['arena_static_bytes'])} / {n(cs[k]['arena_high_water_bytes'])} B",
        ),
        ("arena high-water, native pathway", lambda k: f"{n(runs[k]['native']['arena_used'])} B"),
        ("of the arena: the refinement's state", lambda k: f"{n(cs[k]['refine_arena_bytes'])} B"),
        (
            "stack peak / reserved",
            lambda k: f"{n(cs[k]['stack_peak_bytes'])} / {n(cs[k]['stack_reserved_bytes'])} B",
        ),
        (
            "RAM reserved (`.data .bss .uninit` + stack)",
            lambda k: f"{n(cs[k]['ram_reserved_bytes'])} B",
        ),
        (
            "the E7 frame's arena, static / high-water (`--frame320`, in SRAM)",
            lambda k: e7_arena(runs[k]),
        ),
        (
            "QEMU wall time of the run (every run of the firmware)",
            lambda k: f"{cs[k]['qemu_wall_seconds']:.0f} s",
        ),
    ]
    rows = [[name] + [get(k) for k in CORES] for name, get in spec]
    return table(["memory"] + [core_label(cs[k]) for k in CORES], rows) + "\n\n" + footer(src)


STAGE_NOTES = {
    "load": "load (blob CRC and parse, once per pathway at boot)",
    "rows": "rows (camera rows from the interrupt into the band buffer)",
    "encode_left": "encode_left: encoder on (L, L)",
    "encode_right": "encode_right: encoder on (R, R)",
    "match": "match (inverse norms, cost row, WTA)",
    "sgm": "sgm (two streams)",
    "left_right": "left_right",
    "head": "head (the left head, then the mirrored head for its check, fused with the SGM rows)",
    "refine": "refine (pixel refinement of the fuse-all+lr grid, depth sectors)",
    "native_rows": "native_rows",
    "native_encode_pair": "native_encode_pair: one pass on (L, R)",
    "native_sgm": "native_sgm: the census SGM (census codes, cell costs, two streams)",
    "native_head": "native_head: the native head on the pair tokens, its check from its logits, fused with the census rows",
    "native_refine": "native_refine: pixel refinement of the fuse-census+lr grid, depth sectors",
}


def fw_stages(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    stages = {k: {s["name"]: s for s in cs[k]["stages"]} for k in CORES}
    names = sorted(
        (s["name"] for s in cs["m55"]["stages"]),
        key=lambda s: list(STAGE_NOTES).index(s) if s in STAGE_NOTES else len(STAGE_NOTES),
    )
    rows = []
    for name in names:
        row = [STAGE_NOTES.get(name, name), n(stages["m55"][name]["arena_in_use_bytes"])]
        for k in CORES:
            # A stage only one core ran (the E7 frame's: the M55's) is a dash on the other.
            s = stages[k].get(name)
            row += [n(s["instructions"]), f"{s['estimated_ms']:,.1f}"] if s else ["-", "-"]
        rows.append(row)

    def total(label: str, key: str, arena: str) -> list[str]:
        row = [f"**{label}**", arena]
        for k in CORES:
            c = cs[k]
            ins = c[key]
            row += [f"**{n(ins)}**", f"**{ins / (c['clock_mhz'] * 1e3):,.1f}**"]
        return row

    rows.append(
        total(
            "band pair, export pathway (all but load and native_*)",
            "band_pair_instructions",
            n(cs["m55"]["arena_high_water_bytes"]),
        )
    )
    rows.append(
        total(
            "band pair, native pathway with the head's check (all native_*)",
            "native_band_pair_instructions",
            n(src.run("m55")["native"]["arena_used"]),
        )
    )
    header = ["stage", "arena in use B"]
    for k in CORES:
        header += [
            f"{k.upper()} instructions",
            f"{k.upper()} ms at {cs[k]['clock_mhz']:.0f} MHz, IPC 1",
        ]
    return table(header, rows) + "\n\n" + footer(src)


# Instruction ceilings per export band pair that the kernels were tuned against; the budget file
# judges the time targets.
def fw_targets(src: Sources) -> str:
    b = src.budget()
    rows = [[t["target"], t["measured"], "met" if t["met"] else "**missed**"] for t in b["targets"]]
    return (
        table(["target", "measured", "state"], rows, [False, False, False]) + "\n\n" + footer(src)
    )


def fw_camera(src: Sources) -> str:
    cams = {k: src.run(k)["camera"] for k in CORES}
    cs = {k: src.core(k) for k in CORES}
    spec: list[tuple[str, Callable[[Json], str]]] = [
        ("band pair, export pathway, instructions", lambda c: n(c["band_pair_instructions"])),
        (
            "rows stage per row (interrupt included), instructions",
            lambda c: f"{c['rows_stage_instructions_per_row']:,.0f}",
        ),
        ("frames (48 rows, 160 px) per second", lambda c: f"{c['frames_per_s']:.3f}"),
        (
            "rows/s, framed sensor (blanked while the pipeline works)",
            lambda c: f"{c['framed_rows_per_s']:.2f}",
        ),
        (
            f"rows/s, sensor that never pauses ({cams['m55']['line_buffers']} line buffers)",
            lambda c: f"{c['continuous_rows_per_s']:.2f}",
        ),
        (
            "in-frame burst the rows stage drains, rows/s",
            lambda c: n(round(c["burst_rows_per_s"], -3)),
        ),
        ("rows delivered / lost in the run", lambda c: f"{c['delivered']} / {c['lost']}"),
    ]
    rows = [[name] + [get(cams[k]) for k in CORES] for name, get in spec]
    header = ["IPC-1 figures"] + [
        f"{core_label(cs[k]).split(' (')[0]} at {cs[k]['clock_mhz']:.0f} MHz" for k in CORES
    ]
    return table(header, rows) + "\n\n" + footer(src)


def fw_cycle_model(src: Sources) -> str:
    cs = {k: src.core(k) for k in CORES}
    rows = []
    for stage in ("encode_left", "head"):
        row = [stage]
        for k in CORES:
            s = next(s for s in cs[k]["stages"] if s["name"] == stage)
            row += [
                f"{s['estimated_ms']:,.0f} ms",
                f"{mega(s['modelled_cycles'])} cycles, {s['modelled_ms']:,.0f} ms",
            ]
        rows.append(row)
    row = ["**band pair** (export pathway, all but load)"]
    for k in CORES:
        c, cm = cs[k], cs[k]["cycle_model"]
        per = cm["band_pair_modelled_cycles"] / c["band_pair_instructions"]
        row += [
            f"**{c['band_pair_estimated_ms']:,.0f} ms**",
            f"**{mega(cm['band_pair_modelled_cycles'])} cycles, "
            f"{cm['band_pair_modelled_ms']:,.0f} ms "
            f"({per:.2f} per instruction)**",
        ]
    rows.append(row)
    header = ["stage"]
    for k in CORES:
        header += [f"{k.upper()} IPC 1", f"{k.upper()} modelled"]
    return table(header, rows) + "\n\n" + footer(src)


# ---------------------------------------------------------------- weights


def weights_files(src: Sources) -> str:
    man = src.json(MANIFEST)
    rows = [
        [f"`{name}`", n(src.size(f"weights/{name}")), f"`{sha[:16]}…`"]
        for name, sha in man["files"].items()
    ]
    return (
        table(["file", "bytes", "sha256 (manifest)"], rows, [False, True, False])
        + "\n\n"
        + footer(src)
    )


def shipped_head(run: Json) -> str:
    """"last", or the interpolation `head_interpolate` made between two runs' heads."""
    mix = run.get("interpolated")
    if not mix:
        return "last"
    start, end = (Path(mix[k]).parent.name for k in ("start", "end"))
    return f"{mix['alpha']:g} of the way from `{start}` to `{end}` (weights)"


def training_summary(src: Sources) -> str:
    man = src.json(MANIFEST)
    pre, head, nat = man["pretraining"], man["head_training"], man["native_head_training"]
    hw = man["hardware"]
    rows = [
        [
            "encoder pretraining (self-supervised)",
            f"{n(pre['pairs_seen'])} pairs, {n(pre['steps'])} steps",
            f"{pre['train_seconds'] / 3600:.1f} h",
            f"`{pre['shipped_checkpoint']}`",
        ],
        [
            "shared head",
            f"{n(head['steps'])} steps",
            f"{head['train_seconds'] / 3600:.1f} h",
            shipped_head(head),
        ],
        ["native head", f"{n(nat['steps'])} steps", f"{nat['train_seconds'] / 3600:.1f} h", shipped_head(nat)],
    ]
    text = table(["model", "training", "time", "shipped"], rows, [False, False, True, False])
    text += (
        f"\n\nTraining pairs: {len(man['training_pairs'])} (the train split of `../shared/data`); "
        f"trained on {hw['cpu']}, {hw['torch_threads']} threads, "
        f"torch {hw['torch']}, CUDA {hw['cuda']}."
    )
    return text + "\n\n" + footer(src)


def blob_size(src: Sources) -> str:
    rows = []
    for path, what in [
        ("weights/bino_int8.bin", "encoder, shared and native head: the QEMU firmware's, both pathways"),
        ("weights/bino_int8_native.bin", "encoder and native head: the boards' learned preset"),
    ]:
        b = src.size(path)
        rows.append([f"`{path}` ({what})", n(b), f"{b / 2**20:.2f}"])
    return table(["shipped int8 blob", "bytes", "MiB"], rows) + "\n\n" + footer(src)


BOARDS = {"stm32h7": "STM32H743", "alif-e7": "Alif E7"}


def board_regions(src: Sources) -> str:
    rows = []
    notes = []
    for board, label in BOARDS.items():
        b = src.json(f"{MEASURED}/board-{board}.json")
        modified = " (engine or boards modified)" if b["core_or_boards_modified"] else ""
        notes.append(f"{label} at `{b['commit']}`{modified}")
        for i, r in enumerate(b["regions"]):
            sections = ", ".join(f"`{name}` {n(size)}" for name, size in r["sections"].items())
            if r["stack_above"] is not None:
                sections += f"; the stack gets the other {n(r['stack_above'])}"
            rows.append(
                [
                    label if i == 0 else "",
                    f"`{r['name']}`",
                    n(r["used"]),
                    n(r["size"]),
                    pct(100 * r["used"] / r["size"]),
                    sections,
                ]
            )
    header = ["board", "region", "used B", "size B", "use", "sections (B)"]
    text = table(header, rows, [False, False, True, True, True, False])
    return text + "\n\nBuilt from: " + "; ".join(notes) + ".\n\n" + footer(src)


def board_e7_frame(src: Sources) -> str:
    """Both presets on the Alif E7's 320x240 test frame as `bino run --profile native` runs them
    (the board's host test holds the board's code to the same digest and arena)."""
    h = src.json(f"{MEASURED}/host-frame-320x240.json")
    f = h["frame"]
    rows = [
        [
            f"{f['width']}x{f['height']}",
            r["preset"],
            f"`{r['readout']}`",
            f"`{r['command']}`",
            f"`{r['refined']}`",
            f"{n(r['arena_bytes'])} B",
            f"{n(r['arena_used'])} B",
        ]
        for r in h["runs"]
    ]
    header = ["frame", "preset", "readout", "command", "refined CRC-32", "arena (exact)"]
    header.append("arena used")
    right = [False] * 5 + [True, True]
    return table(header, rows, right) + "\n\n" + footer(src)


def fw_frames(src: Sources) -> str:
    b = src.budget()
    rows = []
    for e in b["frames"]["estimates"]:
        f = e["frame"]
        rows.append(
            [
                f"{f['width']}x{f['height']}",
                str(e["bands"]),
                f"{core_label(src.core(e['core'])).split(' (')[0]} at {e['clock_mhz']:.0f} MHz",
                e["pathway"],
                mega(e["instructions"]),
                f"{e['seconds_ipc1']:,.1f} s / {fps3(e['frames_per_s_ipc1'])}",
                f"{e['modelled_seconds']:,.1f} s / {fps3(e['modelled_frames_per_s'])}",
                mega(e["fitted_instructions"]),
                f"{n(e['arena_bytes'])} B",
            ]
        )
    header = [
        "frame (W x H)",
        "bands",
        "core",
        "pathway",
        "instructions",
        "IPC 1: s / fps",
        "cycle model: s / fps",
        "fitted through 48x32",
        "arena (exact)",
    ]
    right = [False, True, False, False, True, True, True, True, True]
    return table(header, rows, right) + "\n\n" + footer(src)


PRESET_SOURCES = {
    "measured_frame": "measured on the frame",
    "scaled_frame": "scaled from the measured frame",
    "scaled_band_pair": "scaled from the band pair",
}


def preset_source(p: Json, presets: list[Json]) -> str:
    """Where a preset's figures come from; a scaled frame names the measured frame it was scaled
    from (the core's first measured frame of that preset, as `bino budget` takes it)."""
    if p["source"] != "scaled_frame":
        return PRESET_SOURCES[p["source"]]
    base = next(
        q["frame"]
        for q in presets
        if q["core"] == p["core"] and q["preset"] == p["preset"] and q["source"] == "measured_frame"
    )
    return f"scaled from the measured {base['width']}x{base['height']} frame"


def board_presets(src: Sources) -> str:
    """The board's two presets per frame and core (`bino budget`'s presets): the fast one
    (`census+lr+ref`, no encoder) and the learned one (the native pathway), each counted on the
    firmware's whole frame or scaled (its source says how); frames per second at IPC 1 and under
    the cycle model, the exact arena and the stack peak."""
    b = src.budget()
    rows = []
    for p in b["presets"]["frames"]:
        f = p["frame"]
        modelled = p.get("modelled_frames_per_s")
        rows.append(
            [
                f"{f['width']}x{f['height']}",
                f"{core_label(src.core(p['core'])).split(' (')[0]} at {p['clock_mhz']:.0f} MHz",
                f"{p['preset']}: `{p['readout']}`",
                mega(p["instructions"]),
                preset_source(p, b["presets"]["frames"]),
                fps3(p["frames_per_s_ipc1"]),
                fps3(modelled) if modelled else "-",
                f"{n(p['arena_bytes'])} B",
                f"{n(p['stack_peak_bytes'])} B",
            ]
        )
    header = [
        "frame (W x H)",
        "core",
        "preset",
        "instructions per frame",
        "from",
        "fps at IPC 1",
        "fps, cycle model",
        "arena (exact)",
        "stack peak",
    ]
    right = [False, False, False, True, False, True, True, True, True]
    return table(header, rows, right) + "\n\n" + footer(src)


def board_frames(src: Sources) -> str:
    """The README's board table: per core, both presets on a 160x120 frame (counted on the
    firmware's frame, or scaled: each says which), frames per second at IPC 1 and under the
    cycle model, the exact arena, the weights each needs in flash (the fast one none) and whether
    the firmware's outputs were bit-identical to the host's."""
    b = src.budget()
    rows = []
    for p in b["presets"]["frames"]:
        f = p["frame"]
        if (f["width"], f["height"]) != (160, 120):
            continue
        c = src.core(p["core"])
        modelled = p.get("modelled_frames_per_s")
        how = "counted" if p["source"] == "measured_frame" else "scaled"
        rows.append(
            [
                f"{core_label(c)} at {p['clock_mhz']:.0f} MHz",
                f"{p['preset']}: `{p['readout']}`",
                f"{mega(p['instructions'])} ({how})",
                fps3(p["frames_per_s_ipc1"]),
                fps3(modelled) if modelled else "-",
                f"{n(p['arena_bytes'])} B",
                f"{n(p['weights_bytes'])} B" if p.get("weights_bytes") else "none",
                "yes" if c["outputs_bit_identical"] else "**no**",
            ]
        )
    header = [
        "core (QEMU)",
        "preset",
        "instructions per 160x120 frame",
        "fps at IPC 1",
        "fps, cycle model",
        "arena",
        "weights flash",
        "bit-identical to the host",
    ]
    return table(header, rows) + "\n\n" + footer(src)


def fw_frame_check(src: Sources) -> str:
    checks = src.budget()["frames"]["scaling_check"]
    header = ["stage", "scaled by"]
    for c in checks:
        k = c["core"].upper()
        header += [f"{k} predicted", f"{k} measured", f"{k} error"]
    by = {
        "encoder": "encoder MACs per band",
        "pairs": "rows x candidate pairs",
        "cells": "rows x cells",
    }
    rows = []
    for i, s in enumerate(checks[0]["stages"]):
        name = s["name"] if s.get("scaling") else f"**{s['name']}**"
        row = [name, by.get(s.get("scaling", ""), "")]
        for c in checks:
            t = c["stages"][i]
            row += [n(t["predicted"]), n(t["measured"]), f"{t['error_percent']:+.1f} %"]
        rows.append(row)
    return table(header, rows, [False, False] + [True] * (len(header) - 2)) + "\n\n" + footer(src)
