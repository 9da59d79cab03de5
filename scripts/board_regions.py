"""Memory-region use of a linked board firmware, next to each region's size.

    python3 scripts/board_regions.py --objdump LLVM_OBJDUMP --memory boards/X/memory.x ELF
        [--json OUT]

Reads the regions (NAME : ORIGIN = ..., LENGTH = ...) from the board's memory.x and the
allocated sections from `llvm-objdump -h`; a section counts in the region of its run address,
and a section copied at boot (.data) once more in the region of its load address. The RAM
region's free space above its sections is the stack. Exits 1 if a region overflows or a
section lies outside every region (the linker fails first on an overflow; this is the same
check from the ELF). `--json OUT` also writes the table as JSON (`bino-board-regions/1`), with
the commit it was built from; `scripts/boards.sh --out DIR` writes one per board, and
`scripts/render_docs.py` renders docs/boards.md's table from the committed ones.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from dataclasses import dataclass, field

REGION = re.compile(
    r"^\s*(\w+)\s*(?:\([^)]*\))?\s*:\s*ORIGIN\s*=\s*(\w+)\s*,\s*LENGTH\s*=\s*(\w+)", re.M
)
HEX = r"([0-9a-f]{8})"
SECTION = re.compile(rf"^\s*\d+\s+(\S+)\s+{HEX}\s+{HEX}\s+{HEX}\s+(DATA|TEXT|BSS)\s*$")


@dataclass
class Region:
    name: str
    origin: int
    length: int
    used: int = 0
    top: int = 0
    sections: list[str] = field(default_factory=list)
    sizes: dict[str, int] = field(default_factory=dict)

    def holds(self, address: int) -> bool:
        return self.origin <= address < self.origin + self.length

    def add(self, section: str, address: int, size: int) -> None:
        self.used += size
        self.top = max(self.top, address + size)
        self.sections.append(section)
        self.sizes[section] = size


def size_of(text: str) -> int:
    """A linker-script length or address: 0x.., decimal, or with a K / M suffix."""
    scale = {"K": 1024, "M": 1024 * 1024}.get(text[-1].upper(), 1)
    digits = text[:-1] if scale != 1 else text
    return int(digits, 0) * scale


def regions_of(memory_x: str) -> list[Region]:
    with open(memory_x, encoding="utf-8") as f:
        text = re.sub(r"/\*.*?\*/", "", f.read(), flags=re.S)
    found = [Region(m[1], size_of(m[2]), size_of(m[3])) for m in REGION.finditer(text)]
    if not found:
        sys.exit(f"{memory_x}: no MEMORY regions found")
    for r in found:
        r.top = r.origin
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objdump", required=True, help="llvm-objdump of the Rust toolchain")
    parser.add_argument("--memory", required=True, help="the board's memory.x")
    parser.add_argument("--json", help="also write the regions' use to this file (JSON)")
    parser.add_argument("elf")
    args = parser.parse_args()

    regions = regions_of(args.memory)
    dump = [args.objdump, "-h", args.elf]
    table = subprocess.run(dump, check=True, capture_output=True, text=True).stdout
    status = 0

    def place(section: str, address: int, size: int) -> None:
        nonlocal status
        region = next((r for r in regions if r.holds(address)), None)
        if region is None:
            where = f"0x{address:08x}"
            print(f"  {args.elf}: section {section} at {where} lies in no region of {args.memory}")
            status = 1
            return
        region.add(section, address, size)

    for line in table.splitlines():
        m = SECTION.match(line)
        if not m or int(m[2], 16) == 0:
            continue
        name, size, vma, lma, kind = m[1], int(m[2], 16), int(m[3], 16), int(m[4], 16), m[5]
        place(name, vma, size)
        if kind != "BSS" and lma != vma:
            place(f"{name}(load)", lma, size)

    print(f"  {'region':<8} {'origin':<10} {'used B':>11} {'size B':>11} {'use':>6}  sections")
    for r in regions:
        note = ""
        if r.name == "RAM":
            note = f"; stack {r.origin + r.length - r.top:,} B above them"
        share = 100 * r.used / r.length
        figures = f"0x{r.origin:08x} {r.used:>11,} {r.length:>11,} {share:>5.1f}%"
        print(f"  {r.name:<8} {figures}  {' '.join(r.sections)}{note}")
        if r.used > r.length:
            print(f"  region {r.name} overflows by {r.used - r.length:,} bytes")
            status = 1
    if args.json:
        write_json(args.json, args.elf, args.memory, regions)
    return status


def git(*argv: str) -> str:
    run = subprocess.run(["git", *argv], capture_output=True, text=True, check=False)
    return run.stdout.strip()


def write_json(path: str, elf: str, memory: str, regions: list[Region]) -> None:
    """The regions' use, the commit and whether the engine or the boards differed from it."""
    report = {
        "schema": "bino-board-regions/1",
        "board": memory.rstrip("/").split("/")[-2],
        "elf": elf.split("/")[-1],
        "commit": git("rev-parse", "--short", "HEAD"),
        "core_or_boards_modified": bool(git("status", "--porcelain", "--", "core", "boards")),
        "regions": [
            {
                "name": r.name,
                "origin": r.origin,
                "size": r.length,
                "used": r.used,
                "stack_above": r.origin + r.length - r.top if r.name == "RAM" else None,
                "sections": r.sizes,
            }
            for r in regions
        ],
    }
    with open(path, "w", encoding="utf-8") as f:
        json.dump(report, f, indent=1)
        f.write("\n")
    print(f"  wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
