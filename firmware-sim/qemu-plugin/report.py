#!/usr/bin/env python3
"""One firmware run under QEMU -> out/firmware/<core>.json (stdlib only; scripts/firmware.sh).

Reads the decoded defmt log (lines "bino key=value ..."), the instruction-count plugin's table,
the ELF's section sizes (llvm-size -A) and, with --profile, the plugin's per-block counts, which
it maps to functions with llvm-nm into a per-function profile. Instruction counts are executed
instructions counted by the plugin, not cycles.
"""

import argparse
import bisect
import hashlib
import json
import re
import subprocess
import sys

NOTE = (
    "instructions are executed instructions counted by a QEMU TCG plugin (qemu-plugin/insn_count.c) "
    "between the firmware's stage markers; they are not cycles"
)
CLASS_NOTE = (
    "classes: each stage's executed instructions by class, decoded from the instruction bytes at "
    "translation (qemu-plugin/classify.h); they add up to the stage's instructions. "
    "cycle_adjustments are what the cycle model of qemu-plugin/CYCLES.md prices besides the classes: "
    "MVE instructions overlapping their predecessor, scalar pairs the Cortex-M7 could dual-issue, "
    "words moved beyond the first by multi-word loads/stores"
)
KV = re.compile(r"(\w+)=(\S+)")
# The clocks the budget assumes (bino budget): one instruction per cycle at these rates.
CLOCK_HZ = {"m55": 400_000_000, "m7": 480_000_000}


def number(v):
    try:
        return int(v)
    except ValueError:
        return {"true": True, "false": False}.get(v, v)


def parse_log(path):
    """Every 'bino ...' line as a dict of its key=value pairs."""
    lines = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            at = line.find("bino ")
            if at >= 0:
                raw = dict(KV.findall(line[at + 5 :]))
                fields = {k: number(v) for k, v in raw.items()}
                # Hex digests stay text: one of decimal digits only (14204876) is no number.
                for key in ("digest", "expected", "refined", "bino_run_refined"):
                    if key in raw:
                        fields[key] = raw[key]
                lines.append(fields)
    return lines


def parse_counts(path):
    counts = {}
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            name, insns, entered = line.split("\t")
            counts[name] = (int(insns), int(entered))
    return counts


# The plugin's class columns (classify.h) that partition a stage's instructions; the columns
# after them are the cycle model's adjustments (CYCLES.md), not instructions.
CLASSES = ("mve", "fp", "mul", "div", "load_store", "branch", "loop", "other")
ADJUSTMENTS = ("mve_overlap", "dual_issue_pair", "extra_words")


def parse_classes(path, counts):
    """Per bucket: {"classes": {...}, "adjustments": {...}}, checked against the plain counts."""
    out = {}
    with open(path) as f:
        header = f.readline().rstrip("\n").split("\t")
        if header[1:] != list(CLASSES + ADJUSTMENTS):
            raise ValueError(f"{path}: columns {header[1:]}, expected {CLASSES + ADJUSTMENTS}")
        for line in f:
            if not line.strip():
                continue
            name, *values = line.rstrip("\n").split("\t")
            numbers = [int(v) for v in values]
            if len(numbers) != len(CLASSES + ADJUSTMENTS):
                raise ValueError(f"{path}: {name} has {len(numbers)} columns")
            classes = dict(zip(CLASSES, numbers[: len(CLASSES)], strict=True))
            if sum(classes.values()) != counts.get(name, (0, 0))[0]:
                raise ValueError(
                    f"{path}: {name}'s classes add up to {sum(classes.values())}, "
                    f"its instructions are {counts.get(name)}"
                )
            adjustments = dict(zip(ADJUSTMENTS, numbers[len(CLASSES) :], strict=True))
            out[name] = {"classes": classes, "adjustments": adjustments}
    return out


def elf_sections(llvm_size, elf):
    out = subprocess.run([llvm_size, "-A", elf], check=True, capture_output=True, text=True).stdout
    sections = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith(".") and not parts[0].startswith(".debug"):
            sections[parts[0]] = {"size": int(parts[1]), "addr": int(parts[2])}
    return sections


def profile(llvm_nm, elf, blocks_path, top):
    """Instructions per function: each block's count goes to the symbol it starts in."""
    out = subprocess.run(
        [llvm_nm, "--defined-only", "-n", "-C", elf], check=True, capture_output=True, text=True
    ).stdout
    starts, names = [], []
    for line in out.splitlines():
        parts = line.split(None, 2)
        if len(parts) == 3 and parts[1] in "tTwW":
            starts.append(int(parts[0], 16) & ~1)
            names.append(parts[2])
    per = {}
    blocks = []
    total = 0
    with open(blocks_path) as f:
        for line in f:
            if line.startswith("#"):
                continue
            vaddr, n, executed = line.split("\t")
            insns = int(n) * int(executed)
            i = bisect.bisect_right(starts, int(vaddr, 16)) - 1
            name = names[i] if i >= 0 else "?"
            per[name] = per.get(name, 0) + insns
            blocks.append((insns, vaddr, int(n), int(executed), name))
            total += insns
    ranked = sorted(per.items(), key=lambda kv: -kv[1])[:top]
    hot = sorted(blocks, reverse=True)[:top]
    return (
        total,
        [{"function": k, "instructions": v, "share": v / total} for k, v in ranked],
        [
            {
                "address": b[1],
                "block_instructions": b[2],
                "executions": b[3],
                "instructions": b[0],
                "function": b[4],
            }
            for b in hot
        ],
    )


def camera_rates(camera, stages, clock_hz):
    """The sensor row rates the pipeline keeps up with, from the executed instructions (IPC 1).

    The pipeline reads a band's rows in its rows stage, then works on the band without reading
    any (encoder, readouts, head, refinement). A sensor that never pauses keeps exposing rows
    meanwhile; they wait in the line buffers, so it may run at most `line_buffers` rows ahead per
    band's work. A sensor with vertical blanking delivers its frame in a burst and waits; the burst
    may go as fast as the rows stage drains lines (its instructions per row include the interrupt).
    """
    if not camera or not stages or not clock_hz:
        return None
    by_name = {s["name"]: s["instructions"] for s in stages}
    # The export pathway's band pair (the native run's and the whole frames' stages are named
    # native_*, census_*, frame_*, census320_*, frame320_*).
    band = sum(
        n for name, n in by_name.items() if name != "load" and not name.startswith(OTHER_RUN_PREFIXES)
    )
    rows_insns = by_name.get("rows", 0)
    work = band - rows_insns
    frame_rows = camera["frame_rows"]
    lines = camera["line_buffers"]
    if band <= 0 or work <= 0 or frame_rows <= 0:
        return None
    per_row = rows_insns / frame_rows
    return {
        "clock_hz": clock_hz,
        "frame_rows": frame_rows,
        "line_buffers": lines,
        "row_interval_insns": camera["row_interval_insns"],
        "configured_rows_per_s": clock_hz / camera["row_interval_insns"],
        "delivered": camera["delivered"],
        "lost": camera["lost"],
        "queue_high_water": camera["queue_high_water"],
        "band_pair_instructions": band,
        "rows_stage_instructions_per_row": round(per_row, 1),
        "frames_per_s": clock_hz / band,
        "framed_rows_per_s": frame_rows * clock_hz / band,
        "continuous_rows_per_s": min(lines, frame_rows) * clock_hz / work,
        "burst_rows_per_s": clock_hz / per_row if per_row > 0 else None,
        "note": (
            "IPC-1 figures (executed instructions at one per cycle at clock_hz), not cycles. "
            "framed: a frame of frame_rows rows per band pair, the sensor blanked while the pipeline "
            "works; continuous: a sensor that never pauses may run line_buffers rows ahead during the "
            "band's work; burst: the fastest in-frame row rate the rows stage drains"
        ),
    }


# Each whole-frame run's header line: (its frame's key, its arena's key). The census run's is
# "bino census frame=HxW arena_bytes=N", the learned frame's "bino learned_frame=HxW
# learned_arena_bytes=N", the E7 frame's (Cortex-M55, --frame320) one line for both.
FRAME_HEADS = {
    "census": ("frame", "arena_bytes"),
    "frame": ("learned_frame", "learned_arena_bytes"),
    "census320": ("e7_frame", "census320_arena_bytes"),
    "frame320": ("e7_frame", "frame320_arena_bytes"),
}
# The stages of the runs that are not the band pair's: native_*, then the whole frames'.
OTHER_RUN_PREFIXES = ("native_",) + tuple(f"{name}_" for name in FRAME_HEADS)


def whole_frame_run(lines, stages, name):
    """A whole-frame run (stages <name>_*): the fast preset's (census, census320: its frame,
    arena, census rows kept) or the learned preset's (frame, frame320: also its instructions per
    stage and head rows kept), with its stack, instructions per frame and camera; for the E7
    frame's runs also `bino run`'s refined digest of the frame and whether the run's matched it.
    None for a firmware without it."""
    frame_key, arena_key = FRAME_HEADS[name]
    head = next((l for l in lines if frame_key in l and arena_key in l), None)
    arena = next((l for l in lines if "arena_used" in l and l.get("pathway") == name), {})
    camera = next((l for l in lines if "frame_rows" in l and l.get("pathway") == name), {})
    own = [s for s in stages if s["name"].startswith(name + "_")]
    if head is None or not own or not any(s["instructions"] for s in own):
        return None
    height, width = (int(x) for x in str(head[frame_key]).split("x"))
    learned = name.startswith("frame")
    parts = ("pixels", "streams", "refine")
    if learned:
        parts = ("pixels", "encoder", "streams", "refine")
    kept = "head_kept" if learned else "census_kept"
    run = {
        "frame": {"height": height, "width": width},
        "arena_bytes": head.get(arena_key),
        "arena_used": arena.get("arena_used"),
        "arena_painted_high_water": arena.get("painted_high_water"),
        "arena_breakdown": {k: arena.get(k) for k in parts},
        kept: arena.get(kept),
        "frame_instructions": sum(s["instructions"] for s in own),
    }
    if learned:
        run["stages"] = {s["name"]: s["instructions"] for s in own}
    run["stack_peak"] = max(s["stack_peak"] for s in own)
    run["camera"] = {
        k: camera.get(k)
        for k in ("frame_rows", "line_buffers", "row_interval_insns", "delivered", "lost", "queue_high_water")
    }
    bino_run = next(
        (l for l in lines if "bino_run_refined" in l and l.get("pathway") == name), None
    )
    if bino_run is not None:
        run["bino_run"] = {
            "refined": bino_run["refined"],
            "bino_run_refined": bino_run["bino_run_refined"],
            "match": bino_run["bino_run_match"],
            "recorded_in": "firmware-sim/measured/host-frame-320x240.json",
        }
    return run


def sha256_file(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def source_state():
    """The commit measured, and whether core/, firmware-sim/ (but its results) or weights/ differed."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], check=False, capture_output=True, text=True
        ).stdout
        dirty = subprocess.run(
            [
                "git",
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
                "core",
                "firmware-sim",
                "weights",
                ":!firmware-sim/measured",
            ],
            check=False,
            capture_output=True,
            text=True,
        ).stdout
        return {"commit": head.strip() or None, "core_or_firmware_modified": bool(dirty.strip())}
    except OSError:
        return {"commit": None, "core_or_firmware_modified": None}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    for a in (
        "core",
        "cpu",
        "board",
        "target",
        "elf",
        "log",
        "counts",
        "llvm-size",
        "llvm-nm",
        "out",
        "qemu",
    ):
        ap.add_argument("--" + a, required=True)
    ap.add_argument("--wall", type=float, required=True)
    ap.add_argument("--exit-status", type=int, required=True)
    ap.add_argument("--classes", help="the plugin's per-class counts, for the cycle model")
    ap.add_argument("--profile")
    ap.add_argument("--profile-out")
    args = ap.parse_args()

    lines = parse_log(args.log)
    header = next((l for l in lines if "band" in l), {})
    stage_lines = [l for l in lines if "stage" in l]
    outputs = [l for l in lines if "output" in l]
    # One arena line per pathway run (export first; an older firmware's has no pathway field).
    arena = next((l for l in lines if "arena_used" in l and l.get("pathway", "export") == "export"), {})
    native_arena = next((l for l in lines if "arena_used" in l and l.get("pathway") == "native"), {})
    camera = next((l for l in lines if "frame_rows" in l and l.get("pathway", "export") == "export"), {})
    overflow = next((l for l in lines if "queued_rows_read" in l), {})
    result = next((l.get("result") for l in lines if "result" in l), "none")
    counts = parse_counts(args.counts)
    # The plugin's buckets (startup, each stage, outside) partition every executed instruction.
    buckets = sum(n for name, (n, _) in counts.items() if name != "total")
    if buckets != counts.get("total", (None, 0))[0]:
        print(
            f"report.py: stage counts add up to {buckets}, plugin total {counts.get('total')}",
            file=sys.stderr,
        )
        return 1

    try:
        classes = parse_classes(args.classes, counts) if args.classes else {}
    except (OSError, ValueError) as e:
        print(f"report.py: {e}", file=sys.stderr)
        return 1

    height, width = (int(x) for x in str(header.get("band", "0x0")).split("x"))
    stages = []
    for l in stage_lines:
        insns, entered = counts.get(l["stage"], (0, 0))
        stages.append(
            {
                "name": l["stage"],
                "instructions": insns,
                "marker_hits": entered,
                "arena_in_use": l["arena_in_use"],
                "stack_peak": l["stack_peak"],
                **(
                    {
                        "classes": classes[l["stage"]]["classes"],
                        "cycle_adjustments": classes[l["stage"]]["adjustments"],
                    }
                    if l["stage"] in classes
                    else {}
                ),
            }
        )
    report = {
        "schema": "bino-firmware-run/1",
        "core": args.core,
        "cpu": args.cpu,
        "board": args.board,
        "target": args.target,
        "qemu": args.qemu,
        "source": source_state(),
        "band": {"height": height, "width": width},
        "exit_status": args.exit_status,
        "passed": args.exit_status == 0 and result == "pass",
        "result": result,
        "qemu_wall_seconds": round(args.wall, 1),
        "elf": args.elf,
        "elf_sha256": sha256_file(args.elf),
        "elf_sections": elf_sections(args.llvm_size, args.elf),
        "blob_bytes": header.get("blob_bytes"),
        "arena_bytes": header.get("arena_bytes"),
        "arena_used": arena.get("arena_used"),
        "arena_painted_high_water": arena.get("painted_high_water"),
        "arena_breakdown": {k: arena.get(k) for k in ("pixels", "descriptors", "encoder", "streams", "refine")},
        "stack_bytes": header.get("stack_bytes"),
        "stack_peak": max((s["stack_peak"] for s in stages), default=None),
        "stages": stages,
        "startup_instructions": counts.get("startup", (0, 0))[0],
        "outside_instructions": counts.get("outside", (0, 0))[0],
        "total_instructions": counts.get("total", (0, 0))[0],
        "outputs": [
            {
                "pathway": o.get("pathway", "export"),
                "name": o["output"],
                "digest": o["digest"],
                "expected": o["expected"],
                "match": o["match"],
            }
            for o in outputs
        ],
        "camera": camera_rates(camera, stages, CLOCK_HZ.get(args.core)),
        "camera_overflow_check": {k: overflow.get(k) for k in ("exposed", "lost", "queued_rows_read", "ok")},
        "nearest_sector": next(
            ({"sector": l["nearest_sector"], "nearest_mm": l["nearest_mm"]} for l in lines if "nearest_sector" in l),
            None,
        ),
        "wta_kept": arena.get("wta_kept"),
        "sgm_kept": arena.get("sgm_kept"),
        # The native pathway's run (stages native_*): its arena; absent for an older firmware.
        "native": (
            {
                "arena_used": native_arena.get("arena_used"),
                "arena_painted_high_water": native_arena.get("painted_high_water"),
                "arena_breakdown": {k: native_arena.get(k) for k in ("pixels", "encoder", "streams", "refine")},
                "head_kept": native_arena.get("head_kept"),
            }
            if native_arena
            else None
        ),
        # The fast preset's whole frame (stages census_*); absent for an older firmware.
        "census": whole_frame_run(lines, stages, "census"),
        # The learned preset's whole frame (stages frame_*); absent for an older firmware.
        "frame": whole_frame_run(lines, stages, "frame"),
        # Both on the Alif E7's 320x240 frame (stages census320_*, frame320_*: the Cortex-M55
        # with scripts/firmware.sh --frame320); null where the firmware did not run them.
        "census320": whole_frame_run(lines, stages, "census320"),
        "frame320": whole_frame_run(lines, stages, "frame320"),
        "note": NOTE,
    }
    if classes:
        report["class_note"] = CLASS_NOTE
    if args.profile:
        total, top, hot = profile(args.llvm_nm, args.elf, args.profile, 40)
        report["profile_top_functions"] = top[:15]
        if args.profile_out:
            with open(args.profile_out, "w") as f:
                f.write(f"# {args.core}: executed instructions per function (top {len(top)}; not cycles)\n")
                f.writelines(
                    f"{t['instructions']:>14,}  {100 * t['share']:5.1f}%  {t['function']}\n" for t in top
                )
                f.write(f"{total:>14,}  100.0%  total\n")
                f.write(
                    "\n# hottest translation blocks (llvm-objdump -d --start-address=ADDR to read them)\n"
                )
                f.write("#  instructions  share  address  insns/exec  executions  function\n")
                f.writelines(
                    f"{b['instructions']:>14,}  {100 * b['instructions'] / total:5.1f}%  {b['address']}  "
                    f"{b['block_instructions']:>4}  {b['executions']:>12,}  {b['function']}\n"
                    for b in hot
                )
    cam = report["camera"]
    if cam:
        print(
            f"{args.core}: camera {cam['delivered']} rows, {cam['lost']} lost; keeps up (IPC 1, "
            f"{cam['clock_hz'] / 1e6:.0f} MHz) with {cam['framed_rows_per_s']:.2f} rows/s in "
            f"{cam['frame_rows']}-row frames ({cam['frames_per_s']:.3f} frames/s), "
            f"{cam['continuous_rows_per_s']:.2f} rows/s from a sensor that never pauses "
            f"({cam['line_buffers']} line buffers), bursts up to {cam['burst_rows_per_s']:,.0f} rows/s"
        )
    with open(args.out, "w") as f:
        json.dump(report, f, indent=2)
        f.write("\n")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
