"""The shared stereo head (DESIGN.md, Readouts): frozen descriptor maps -> token-grid disparity.

    python -m bino_train.head                                         # parameter count
    python -m bino_train.head --checkpoint runs/NAME/last.pt --out weights/bino_head.onnx
    python -m bino_train.head --native-fixture ../tests/fixtures/native_head_random_seed0.onnx

Data flow, all on the token grid (T = H/4 rows, P = W/4 patch columns):
  D_L, D_R (B, T, P, 128) -> the same LayerNorm + Linear 128 -> C on both views
  -> groupwise correlation corr[g, k, r, p] = mean over the C/G channels of group g of
     f_L[r, p] * f_R[r, p - k], k = 0 .. D-1 (zero where p - k < 0)
  -> 3D regularisation over (disparity, row, column): Conv3d 3x3x3, ReLU, residual middle layers
  -> logits (B, D, T, P), candidates with p - k < 0 pushed to -1e4
  -> softmax over k: soft-argmin disparity sum_k k * prob_k (patch columns, 4 px each at the
     encoder's input) and confidence max_k prob_k.

The native head (`HeadConfig.pair_features` "concat" or "full", the native pathway of
DESIGN.md) reads the phase maps a, b (even and odd fused columns of one encoder pass on (L, R))
instead: each fused token covers 4 rows x 2 columns of both views, so a and b each hold left and
right content and a single shared projection cannot tell them apart. It forms pair features
u = [a, b] ("concat") or the paper's u = [a, b, |a - b|, a * b] ("full"; |x| as
relu(a - b) + relu(b - a), inside the op set below), one LayerNorm over u, then two projections
f_L = P_L(u), f_R = P_R(u) correlated exactly as above (f_L[p] * f_R[p - k]), then the same
regularisation and soft-argmin.

Everything is convolutional in (row, column), so any T x P grid works: 48-row training crops,
and full eval images described band by band. The correlation is built from one zero block and
a constant-bound slice per candidate, so the ONNX graph holds only LayerNormalization, MatMul,
Add, Sub, Mul, Concat, Slice, Unsqueeze, Squeeze, Transpose, Conv (3D), Relu, Softmax,
ReduceSum and ReduceMax, and no shape arithmetic (all of them are tract-onnx 0.23 ops).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import PAPER_CONFIG
from .export import stamp_metadata
from .model import encoder_macs, parameter_count

OPSET = 17
MASKED_LOGIT = 1e4
"""Subtracted from the logits of candidates outside the right image (finite, so int8-friendly)."""


PAPER_HEAD_MAX_DISP = 12
"""The candidates the heads are trained with (HeadConfig.max_disp's default)."""

PAIR_FEATURES = ("", "concat", "full")
"""HeadConfig.pair_features: "" the shared (export-pathway) head, else a native head."""


@dataclass(frozen=True)
class HeadConfig:
    desc_dim: int = 128
    proj_dim: int = 96
    groups: int = 16
    hidden: int = 24
    middle_layers: int = 4
    max_disp: int = 12  # PAPER_HEAD_MAX_DISP
    """D: candidates 0 .. D-1 patch columns; D = 12 reaches 44 px at w160: above SGBM's 32 px
    search range and the eval split's largest ground truth at w160 (27.7 px, 7 columns),
    with room for the wider (up to 320 px) training crops."""
    ln_eps: float = 1e-5
    pair_features: str = ""
    """"": the shared head on D(L), D(R) (export pathway); "concat" / "full": the native head on
    the phase maps (module docstring). Checkpoints from before this field load as ""."""

    def __post_init__(self) -> None:
        if self.pair_features not in PAIR_FEATURES:
            raise ValueError(f"pair_features {self.pair_features!r} not in {PAIR_FEATURES}")
        if self.proj_dim % self.groups:
            raise ValueError(f"proj_dim {self.proj_dim} not divisible by groups {self.groups}")
        if self.max_disp < 2:
            raise ValueError("max_disp must be at least 2")

    @property
    def pathway(self) -> str:
        """The encoder outputs this head reads: "export" (D(L), D(R)) or "native" (phase maps)."""
        return "native" if self.pair_features else "export"

    @property
    def pair_dim(self) -> int:
        """Width of the features the LayerNorm sees: desc_dim, or u's width for a native head."""
        return {"": 1, "concat": 2, "full": 4}[self.pair_features] * self.desc_dim

    def to_dict(self) -> dict[str, Any]:
        """The fields; the shared head's without `pair_features`, so its checkpoints and ONNX
        metadata stay as they were before native heads existed."""
        d = asdict(self)
        if not self.pair_features:
            del d["pair_features"]
        return d


PAPER_HEAD = HeadConfig()
PAPER_HEAD_PARAMETERS = 86_000
"""The paper's figure for the shared head (0.086M); the default config is within 0.1% of it."""

NATIVE_HEAD = HeadConfig(pair_features="concat", proj_dim=64)
"""The native head, u = [a, b]: the shared head's regulariser with 64-channel projections (96
would put the head at 15.3 % of an encoder pass at 48x160, over the 15 % budget; head_macs)."""

NATIVE_FULL_HEAD = HeadConfig(pair_features="full", proj_dim=32)
"""The paper's pair features u = [a, b, |a - b|, a * b]: twice u's width, so half the channels."""

NATIVE_HEADS = {"concat": NATIVE_HEAD, "full": NATIVE_FULL_HEAD}


class HeadOutput(NamedTuple):
    logits: Tensor
    """(B, D, T, P), masked candidates at about -1e4."""
    disparity: Tensor
    """(B, T, P) soft-argmin disparity in patch columns."""
    confidence: Tensor
    """(B, T, P) the largest candidate probability."""


def shifted_views(x: Tensor, count: int) -> list[Tensor]:
    """(B, T, P, C) -> [y_0 .. y_{count-1}], y_k[:, :, p] = x[:, :, p - k], zero where p < k.

    One zero block of count - 1 columns on the left, then a static slice per k: in ONNX only
    Mul, Concat and Slice with constant bounds (no Pad with computed pads, no Shape), and the
    width is kept for any P, also P < count.
    """
    zero = x[:, :, :1] * 0.0
    padded = torch.cat([zero] * (count - 1) + [x], dim=2)
    first = count - 1
    return [padded[:, :, first - k : -k] if k else padded[:, :, first:] for k in range(count)]


class StereoHead(nn.Module):
    """The shared head (export pathway): one LayerNorm + projection for both views."""

    def __init__(self, cfg: HeadConfig = PAPER_HEAD) -> None:
        super().__init__()
        self.cfg = cfg
        self.check_config(cfg)
        self.build_features(cfg)
        per_group = cfg.proj_dim // cfg.groups
        # Channel -> group averaging as one MatMul: no reshape with dynamic sizes in the graph.
        group_of = torch.arange(cfg.proj_dim) // per_group
        pool = (group_of[:, None] == torch.arange(cfg.groups)[None, :]).float() / per_group
        self.group_pool: Tensor
        self.candidates: Tensor
        self.register_buffer("group_pool", pool, persistent=False)
        self.register_buffer(
            "candidates", torch.arange(cfg.max_disp, dtype=torch.float32), persistent=False
        )
        self.stem = nn.Conv3d(cfg.groups, cfg.hidden, 3, padding=1)
        self.middle = nn.ModuleList(
            nn.Conv3d(cfg.hidden, cfg.hidden, 3, padding=1) for _ in range(cfg.middle_layers)
        )
        self.out = nn.Conv3d(cfg.hidden, 1, 3, padding=1)

    def check_config(self, cfg: HeadConfig) -> None:
        if cfg.pathway != "export":
            raise ValueError(f"StereoHead is the export head; {cfg.pair_features!r}: NativeHead")

    def build_features(self, cfg: HeadConfig) -> None:
        """The modules before the correlation (registered first: the state dict's order)."""
        self.norm = nn.LayerNorm(cfg.desc_dim, eps=cfg.ln_eps)
        self.proj = nn.Linear(cfg.desc_dim, cfg.proj_dim)

    def features(self, first: Tensor, second: Tensor) -> tuple[Tensor, Tensor]:
        """(f_L, f_R), each (B, T, P, C), from the head's two input maps."""
        return self.project(first), self.project(second)

    @torch.no_grad()
    def init_from(self, first: Tensor, second: Tensor) -> None:
        """Data-dependent init from a few samples of the two input maps (B, T, P, desc_dim)."""
        self.init_projection(torch.cat([first, second]).float())

    @torch.no_grad()
    def init_projection(self, desc: Tensor) -> None:
        """Data-dependent init: the projection becomes centred PCA of LayerNorm(desc).

        Encoder descriptors share a large common vector (about 5-8x the token-to-token
        spread): with a random projection the correlation is mostly that constant and the
        head needs many steps to learn to remove it. Centring, then keeping the top C
        principal directions (scaled to unit mean variance), starts the correlation as an
        inner product of what differs between tokens, which is what matching needs.
        """
        weight, bias = pca_projection(
            self.norm(desc.reshape(-1, self.cfg.desc_dim).float()), self.cfg.proj_dim
        )
        self.proj.weight.copy_(weight)
        self.proj.bias.copy_(bias)

    def project(self, desc: Tensor) -> Tensor:
        """(B, T, P, desc_dim) -> (B, T, P, C); the same weights for both views."""
        return self.proj(self.norm(desc))

    def correlation(self, feat_left: Tensor, feat_right: Tensor) -> Tensor:
        """(B, G, D, T, P): group means of f_L[p] * f_R[p - k]; zero where p - k < 0."""
        slices = [
            torch.matmul(feat_left * shifted, self.group_pool)
            for shifted in shifted_views(feat_right, self.cfg.max_disp)
        ]
        return torch.stack(slices, dim=1).permute(0, 4, 1, 2, 3)

    def candidate_mask(self, desc: Tensor) -> Tensor:
        """(B, D, T, P): 1 where the candidate p - k lies inside the right view, else 0."""
        ones = desc[..., :1] * 0.0 + 1.0  # not ones_like: keeps Shape ops out of the graph
        return torch.cat(shifted_views(ones, self.cfg.max_disp), dim=-1).permute(0, 3, 1, 2)

    def regularise(self, volume: Tensor) -> Tensor:
        """(B, G, D, T, P) -> (B, D, T, P) logits before masking."""
        x = F.relu(self.stem(volume))
        for conv in self.middle:
            x = x + F.relu(conv(x))  # residual: a deep stack of tiny convs still trains quickly
        return self.out(x).squeeze(1)

    def forward(self, desc_left: Tensor, desc_right: Tensor) -> HeadOutput:
        if not torch.onnx.is_in_onnx_export() and desc_left.shape != desc_right.shape:
            raise ValueError(f"{tuple(desc_left.shape)} vs {tuple(desc_right.shape)}")
        volume = self.correlation(*self.features(desc_left, desc_right))
        valid = self.candidate_mask(desc_left)
        logits = self.regularise(volume) - (1.0 - valid) * MASKED_LOGIT
        prob = torch.softmax(logits, dim=1)
        disparity = (prob * self.candidates.view(1, -1, 1, 1)).sum(dim=1)
        confidence = prob.amax(dim=1)
        return HeadOutput(logits, disparity, confidence)


def pca_projection(x: Tensor, dim: int) -> tuple[Tensor, Tensor]:
    """(weight (dim, F), bias (dim,)) projecting rows of x (N, F) onto their top `dim` centred
    principal directions, scaled to unit mean variance (StereoHead.init_projection)."""
    mean = x.mean(dim=0)
    cov = torch.cov((x - mean).T)
    eigval, eigvec = torch.linalg.eigh(cov)  # ascending
    top = eigvec[:, -dim:].flip(-1).T  # (dim, F)
    scale = eigval[-dim:].clamp_min(0).mean().sqrt().clamp_min(1e-6)
    weight = top / scale
    return weight, -(weight @ mean)


class NativeHead(StereoHead):
    """The native-pathway head: pair features of the phase maps, two projections (module doc)."""

    def check_config(self, cfg: HeadConfig) -> None:
        if cfg.pathway != "native":
            raise ValueError("NativeHead needs pair_features 'concat' or 'full'")

    def build_features(self, cfg: HeadConfig) -> None:
        self.norm = nn.LayerNorm(cfg.pair_dim, eps=cfg.ln_eps)
        self.proj_left = nn.Linear(cfg.pair_dim, cfg.proj_dim)
        self.proj_right = nn.Linear(cfg.pair_dim, cfg.proj_dim)

    def pair_features(self, even: Tensor, odd: Tensor) -> Tensor:
        """u (B, T, P, pair_dim) from the phase maps (B, T, P, desc_dim), LayerNorm applied."""
        parts = [even, odd]
        if self.cfg.pair_features == "full":
            # |a - b| as two Relu of Sub: no Abs or Neg in the ONNX graph (op set above).
            parts += [F.relu(even - odd) + F.relu(odd - even), even * odd]
        return self.norm(torch.cat(parts, dim=-1))

    def features(self, first: Tensor, second: Tensor) -> tuple[Tensor, Tensor]:
        u = self.pair_features(first, second)
        return self.proj_left(u), self.proj_right(u)

    @torch.no_grad()
    def init_from(self, first: Tensor, second: Tensor) -> None:
        """Both projections start as the centred PCA of LayerNorm(u) (as the shared head's
        init): the correlation starts as an inner product of what differs between pair
        features, and training separates P_L from P_R (the shifts make their gradients differ).
        """
        u = self.pair_features(first.float(), second.float())
        weight, bias = pca_projection(u.reshape(-1, self.cfg.pair_dim), self.cfg.proj_dim)
        for proj in (self.proj_left, self.proj_right):
            proj.weight.copy_(weight)
            proj.bias.copy_(bias)

    def init_projection(self, desc: Tensor) -> None:
        raise TypeError("a native head starts from both phase maps: init_from(even, odd)")

    def project(self, desc: Tensor) -> Tensor:
        raise TypeError("a native head projects pair features of both maps: features(even, odd)")


def make_head(cfg: HeadConfig) -> StereoHead:
    """The head class a config names: StereoHead (export pathway) or NativeHead."""
    return NativeHead(cfg) if cfg.pathway == "native" else StereoHead(cfg)


@dataclass(frozen=True)
class LossParts:
    loss: Tensor
    smooth_l1: float
    ce: float
    epe_cols: float
    """Mean |soft disparity - target| over the supervised cells, in patch columns."""
    cells: int


def supervised_cells(target: Tensor, max_disp: int) -> Tensor:
    """Cells with a usable target: finite, in [0, D-1], and the rounded target a valid candidate
    (p - round(target) >= 0: columns near the left edge cannot see large disparities)."""
    cols = torch.arange(target.shape[-1], device=target.device).view(1, 1, -1)
    finite = torch.isfinite(target)
    safe = torch.where(finite, target, torch.zeros_like(target))
    return finite & (safe >= 0) & (safe <= max_disp - 1) & (torch.round(safe) <= cols)


def head_loss(
    out: HeadOutput, target: Tensor, ce_weight: float = 1.0, weight: Tensor | None = None
) -> LossParts:
    """Smooth L1 on the soft disparity + cross-entropy on the rounded target, supervised cells
    only, each cell weighted by `weight` (B, T, P) (None: 1). target: (B, T, P) patch columns,
    NaN where unknown."""
    d = out.logits.shape[1]
    mask = supervised_cells(target, d)
    if weight is not None:
        mask = mask & (weight > 0)
    n = int(mask.sum())
    if n == 0:
        zero = out.disparity.sum() * 0.0  # keeps the graph: backward() still works
        return LossParts(zero, 0.0, 0.0, 0.0, 0)
    tgt = target[mask]
    w = weight[mask] if weight is not None else torch.ones_like(tgt)
    w = w / w.sum()
    pred = out.disparity[mask]
    sl1 = (F.smooth_l1_loss(pred, tgt, beta=1.0, reduction="none") * w).sum()
    logits = out.logits.permute(0, 2, 3, 1)[mask]  # (n, D)
    ce = (F.cross_entropy(logits, torch.round(tgt).long(), reduction="none") * w).sum()
    loss = sl1 + ce_weight * ce
    epe = float((pred.detach() - tgt).abs().mean())
    return LossParts(loss, float(sl1.detach()), float(ce.detach()), epe, n)


def head_parameters(cfg: HeadConfig = PAPER_HEAD) -> int:
    return parameter_count(make_head(cfg))


def head_macs(cfg: HeadConfig, rows: int = 12, cols: int = 40) -> int:
    """Multiply-accumulates of one head pass on a rows x cols token grid (48x160 px: 12 x 40):
    projections, the correlation products (each summed into its group), the 3D convolutions
    (zero padding counted, as a dense kernel computes it). LayerNorm, the pair features' |a-b|
    and a*b, and the softmax are elementwise and not counted."""
    cells = rows * cols
    proj = 2 * cells * cfg.pair_dim * cfg.proj_dim  # two views, or P_L and P_R of one u
    corr = cells * cfg.max_disp * cfg.proj_dim
    voxels = cfg.max_disp * cells
    conv = (
        voxels
        * 27
        * (cfg.groups * cfg.hidden + cfg.middle_layers * cfg.hidden * cfg.hidden + cfg.hidden)
    )
    return proj + corr + conv


CANDIDATES_LIMIT = 64
"""The most disparity candidates a head searches (bino_core::config::HEAD_CANDIDATES_LIMIT)."""


def head_candidates(width: int, trained: int = PAPER_HEAD_MAX_DISP) -> int:
    """Disparity candidates of the heads for views `width` px wide (bino_host's
    `readout_eval::head_candidates`, the same rule in every command): the StereoSGBM
    reference's search range at that width (EVAL.md: numDisparities 32 px per 160 px, 64 px =
    16 columns at w320), never fewer than the `trained` 12."""
    sgbm_px = 16 * math.ceil(2 * width / 160)
    return min(max(sgbm_px // 4, trained), CANDIDATES_LIMIT)


def with_candidates(head: StereoHead, candidates: int) -> StereoHead:
    """The same head searching `candidates` disparities (no weight depends on the count: the
    correlation and the 3D convolutions slide along the disparity axis)."""
    if candidates == head.cfg.max_disp:
        return head
    wider = make_head(replace(head.cfg, max_disp=candidates))
    wider.load_state_dict(head.state_dict())
    return wider.to(next(head.parameters()).device).train(head.training)


def load_head(checkpoint: Path, max_disp: int | None = None) -> StereoHead:
    """A head from a head-training checkpoint (`head_config` + `head` state dict); `max_disp`
    overrides its number of candidates ([`with_candidates`])."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    config = HeadConfig(**state["head_config"])
    if max_disp is not None:
        config = replace(config, max_disp=max_disp)
    head = make_head(config)
    head.load_state_dict(state["head"])
    return head.eval()


class _ExportWrapper(nn.Module):
    def __init__(self, head: StereoHead, logits: bool) -> None:
        super().__init__()
        self.head = head
        self.logits = logits

    def forward(self, desc_left: Tensor, desc_right: Tensor) -> tuple[Tensor, ...]:
        out = self.head(desc_left, desc_right)
        if self.logits:
            return out.disparity, out.confidence, out.logits
        return out.disparity, out.confidence


def head_input_names(cfg: HeadConfig) -> list[str]:
    """The export head reads `desc_left`, `desc_right`; a native head `phase_even`, `phase_odd`."""
    return ["phase_even", "phase_odd"] if cfg.pathway == "native" else ["desc_left", "desc_right"]


def head_output_names(logits: bool) -> list[str]:
    return ["disparity", "confidence", "logits"] if logits else ["disparity", "confidence"]


def export_head_onnx(
    head: StereoHead,
    out: Path,
    *,
    provenance: str,
    logits: bool = False,
    rows: int = 12,
    cols: int = 40,
) -> None:
    """Inputs `head_input_names` (1, T, P, desc_dim), T and P dynamic; outputs
    `disparity` and `confidence` (1, T, P) (patch columns), optionally `logits` (1, D, T, P)."""
    cfg = head.cfg
    example = torch.zeros(1, rows, cols, cfg.desc_dim)
    names = head_output_names(logits)
    grid = {1: "token_rows", 2: "patch_cols"}
    inputs = head_input_names(cfg)
    dynamic: dict[str, dict[int, str]] = {name: grid for name in inputs}
    for name in names:
        dynamic[name] = {2: "token_rows", 3: "patch_cols"} if name == "logits" else grid
    out.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        torch.onnx.export(
            _ExportWrapper(head.eval(), logits),
            (example, example),
            str(out),
            input_names=inputs,
            output_names=names,
            dynamic_axes=dynamic,
            opset_version=OPSET,
            dynamo=False,
        )
    meta = {
        "bino.weights": provenance,
        "bino.head_config": repr(cfg.to_dict()),
        "bino.parameters": str(parameter_count(head)),
        "bino.pathway": cfg.pathway,
        "bino.disparity_unit": "patch columns (4 px at the encoder input)",
    }
    stamp_metadata(out, meta)


def write_native_fixture(out: Path) -> None:
    """The int8 engine's native-head test fixture (`tests/tests/int8.rs`): NATIVE_HEAD at its
    seed-0 random init, exported with logits, as the shared head's fixture is."""
    if "weights" in out.resolve().parts:
        sys.exit(f"error: refusing to write a test fixture into weights/ ({out})")
    torch.manual_seed(0)
    head = NativeHead(NATIVE_HEAD)
    export_head_onnx(head, out, provenance="native-head fixture, seed 0 (tests only)", logits=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, help="head checkpoint (head_train last.pt)")
    parser.add_argument("--out", type=Path, help="ONNX file to write")
    parser.add_argument("--logits", action="store_true", help="also output the logits")
    parser.add_argument(
        "--state-dict", type=Path, help="also save {head_config, head} (PyTorch) to this file"
    )
    parser.add_argument(
        "--native-fixture",
        type=Path,
        help="write the test fixture: NATIVE_HEAD at its seed-0 random init, with logits",
    )
    args = parser.parse_args(argv)
    if args.native_fixture is not None:
        write_native_fixture(args.native_fixture)
        print(f"wrote {args.native_fixture}")
        return
    if args.checkpoint is None:
        encoder = encoder_macs(PAPER_CONFIG)
        for name, cfg in [("stereo head", PAPER_HEAD)] + [
            (f"native head ({k})", c) for k, c in NATIVE_HEADS.items()
        ]:
            n, macs = head_parameters(cfg), head_macs(cfg)
            print(
                f"{name}: {n:,} parameters ({n / 1e6:.4f}M), {macs / 1e6:.1f}M MACs at 48x160 "
                f"({100 * macs / encoder:.2f} % of an encoder pass), config {cfg.to_dict()}"
            )
        return
    if args.out is None:
        parser.error("--out is required with --checkpoint")
    if not args.checkpoint.is_file():
        sys.exit(f"error: checkpoint {args.checkpoint} does not exist")
    state = torch.load(args.checkpoint, map_location="cpu", weights_only=False)
    if state.get("encoder_source", {}).get("kind") == "random-init" and (
        "weights" in args.out.resolve().parts
    ):
        sys.exit(f"error: refusing to write a head trained on a random-init encoder ({args.out})")
    trained = HeadConfig(**state["head_config"]).max_disp
    # The export holds the default 12 candidates whatever the count trained with: no weight
    # depends on it, and bino picks each view width's count (head_candidates) at run time.
    head = load_head(args.checkpoint, PAPER_HEAD_MAX_DISP)
    provenance = (
        f"head checkpoint {args.checkpoint.name} at step {state.get('step')}, "
        f"trained with {trained} candidates"
    )
    export_head_onnx(head, args.out, provenance=provenance, logits=args.logits)
    print(f"wrote {args.out} ({parameter_count(head):,} parameters; {provenance})")
    if args.state_dict is not None:
        torch.save({"head_config": head.cfg.to_dict(), "head": head.state_dict()}, args.state_dict)
        print(f"wrote {args.state_dict}")


if __name__ == "__main__":
    main()
