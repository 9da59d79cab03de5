"""ONNX export of the BINO encoder, and the parity fixture the Rust tests read.

    python -m bino_train.export --checkpoint CKPT --out weights/bino_encoder.onnx
    python -m bino_train.export --random-init-seed 0 --out tests/fixtures/x.onnx \
        --intermediates --fixture tests/fixtures/parity

Inputs `left`, `right`: (1, 3, H, W) float32 in [0, 1], H <= 48 and a multiple of 4, W a
multiple of 4 (both dynamic). Output `tokens`: the de-positioned fused token grid
(1, H/4, W/2, 128). With `--intermediates` the graph also outputs `embed` (patch embedding
plus row embedding) and `block0` ... `block6` (residual stream after each block), same layout.

A seeded random initialisation exists for tests only: it is stamped as such in the ONNX
metadata and may not be written into `weights/`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from .config import EncoderConfig
from .model import BinoEncoder, parameter_count, stage_names, uniform_row_embedding
from .synthetic import shifted_pair, to_view_tensor

OPSET = 17


class _StagesWrapper(nn.Module):
    def __init__(self, encoder: BinoEncoder, intermediates: bool) -> None:
        super().__init__()
        self.encoder = encoder
        self.intermediates = intermediates

    def forward(self, left: Tensor, right: Tensor) -> tuple[Tensor, ...]:
        stages = self.encoder.forward_stages(left, right)
        if self.intermediates:
            return (stages[-1], *stages[:-1])
        return (stages[-1],)


def output_names(cfg: EncoderConfig, intermediates: bool) -> list[str]:
    names = stage_names(cfg)
    return [names[-1], *names[:-1]] if intermediates else [names[-1]]


def load_encoder(checkpoint: Path) -> BinoEncoder:
    """Load an encoder from a training checkpoint (`config` + `encoder` state dict)."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    cfg = EncoderConfig(**state["config"])
    encoder = BinoEncoder(cfg)
    encoder.load_state_dict(state["encoder"])
    return encoder.eval()


def random_encoder(seed: int, cfg: EncoderConfig | None = None) -> BinoEncoder:
    torch.manual_seed(seed)
    return BinoEncoder(cfg or EncoderConfig()).eval()


def export_onnx(
    encoder: BinoEncoder, out: Path, *, intermediates: bool, provenance: str, width: int = 160
) -> None:
    cfg = encoder.cfg
    example = torch.zeros(1, cfg.in_chans, cfg.band_rows, width)
    names = output_names(cfg, intermediates)
    # The batch is dynamic too: under row attention a band's token rows can run as a batch of
    # one-row bands (`ort_bench`), the products the int8 engine computes.
    view_axes = {0: "batch", 2: "height", 3: "width"}
    dynamic = {"left": view_axes, "right": view_axes}
    for name in names:
        dynamic[name] = {0: "batch", 1: "token_rows", 2: "fused_cols"}
    out.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        torch.onnx.export(
            _StagesWrapper(encoder, intermediates),
            (example, example),
            str(out),
            input_names=["left", "right"],
            output_names=names,
            dynamic_axes=dynamic,
            opset_version=OPSET,
            dynamo=False,
        )
    meta = {
        "bino.weights": provenance,
        "bino.config": repr(cfg.to_dict()),
        "bino.parameters": str(parameter_count(encoder)),
    }
    stamp_metadata(out, meta)


def stamp_metadata(path: Path, meta: dict[str, str]) -> None:
    """Add `meta` to the ONNX file's metadata (provenance travels with the model), check, save."""
    model = onnx.load(str(path))
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def write_fixture(
    encoder: BinoEncoder, folder: Path, *, width: int = 48, disparity: int = 3
) -> None:
    """Write a procedural input pair and every stage PyTorch computes for it, as .npy."""
    folder.mkdir(parents=True, exist_ok=True)
    left_gray, right_gray = shifted_pair(
        seed=7, height=encoder.cfg.band_rows, width=width, disparity=disparity
    )
    left, right = to_view_tensor(left_gray), to_view_tensor(right_gray)
    with torch.no_grad():
        stages = encoder.forward_stages(torch.from_numpy(left), torch.from_numpy(right))
    np.save(folder / "left.npy", left)
    np.save(folder / "right.npy", right)
    for name, tensor in zip(stage_names(encoder.cfg), stages, strict=True):
        if name in ("embed", "tokens"):
            np.save(folder / f"{name}.npy", tensor.numpy().astype(np.float32))


def _refuse_random_into_weights(out: Path) -> None:
    if "weights" in out.resolve().parts:
        sys.exit(f"error: refusing to write a random initialisation into weights/ ({out})")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--checkpoint", type=Path, help="training checkpoint to export")
    source.add_argument("--random-init-seed", type=int, help="seeded random init (tests only)")
    parser.add_argument("--out", type=Path, required=True, help="ONNX file to write")
    parser.add_argument("--intermediates", action="store_true", help="also output embed, block0..")
    parser.add_argument("--fixture", type=Path, help="folder for a parity fixture (.npy files)")
    parser.add_argument(
        "--state-dict", type=Path, help="also save {config, encoder} (PyTorch) to this file"
    )
    parser.add_argument(
        "--attention-rows",
        type=int,
        help="hold attention to this many token rows either side (0: each row within itself; "
        "the engine runs 0 or, without this option, the whole band)",
    )
    parser.add_argument(
        "--row-embedding",
        type=int,
        metavar="INDEX",
        help="give every token row the row embedding of this row (with --attention-rows 0 a "
        "frame's bands then share their overlap rows, each computed once)",
    )
    args = parser.parse_args(argv)
    if args.attention_rows is not None and args.attention_rows < 0:
        parser.error(f"--attention-rows {args.attention_rows} must be at least 0")

    if args.checkpoint is not None:
        if not args.checkpoint.is_file():
            sys.exit(f"error: checkpoint {args.checkpoint} does not exist")
        encoder = load_encoder(args.checkpoint)
        provenance = f"trained checkpoint {args.checkpoint.name}"
    else:
        _refuse_random_into_weights(args.out)
        encoder = random_encoder(args.random_init_seed)
        provenance = f"random-init seed {args.random_init_seed} (tests only, not trained)"
    if args.attention_rows is not None:
        encoder.cfg = dataclasses.replace(encoder.cfg, attention_rows=args.attention_rows)
    if args.row_embedding is not None:
        rows = encoder.cfg.token_rows
        if not 0 <= args.row_embedding < rows:
            parser.error(f"--row-embedding {args.row_embedding} must be in 0..{rows - 1}")
        uniform_row_embedding(encoder, args.row_embedding)
    export_onnx(encoder, args.out, intermediates=args.intermediates, provenance=provenance)
    print(f"wrote {args.out} ({parameter_count(encoder):,} parameters; {provenance})")
    if args.state_dict is not None:
        torch.save(
            {"config": encoder.cfg.to_dict(), "encoder": encoder.state_dict()}, args.state_dict
        )
        print(f"wrote {args.state_dict}")
    if args.fixture is not None:
        write_fixture(encoder, args.fixture)
        print(f"wrote fixture {args.fixture}")


if __name__ == "__main__":
    main()
