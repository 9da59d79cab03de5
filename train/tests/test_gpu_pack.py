"""The GPU pack: a train-only, downscaled, grayscale data folder the crop sampler reads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bino_train.augment import AugmentConfig, CropSampler
from bino_train.gpu_pack import PACK_INFO, main
from bino_train.pairs import load_gray_u8, load_pairs, training_pairs


def test_pack_is_a_train_only_data_folder(data_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "pack"
    main(["--data", str(data_dir), "--out", str(out), "--max-width", "224", "--quality", "80"])
    packed = load_pairs(out)
    source = {p.pair_id: p for p in training_pairs(data_dir)}
    assert [p.pair_id for p in packed] == list(source)
    assert {p.split for p in packed} == {"train"}
    assert not {"e0", "e1"} & {p.pair_id for p in packed}  # the eval pairs stay out
    for p in packed:
        src = source[p.pair_id]
        assert p.width == min(src.width, 224)
        assert p.height == int(np.floor(src.height * p.width / src.width + 0.5))
        for path in (p.left, p.right):
            assert path.is_relative_to(out)
            assert load_gray_u8(path).shape == (p.height, p.width)  # PAIRS.tsv sizes hold
    info = json.loads((out / PACK_INFO).read_text())
    assert info["pairs"] == 4 and info["quality"] == 80 and info["max_width"] == 224
    assert info["bytes"] > 0


def test_crop_sampler_reads_the_pack(data_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "pack"
    main(["--data", str(data_dir), "--out", str(out), "--max-width", "224"])
    sampler = CropSampler(training_pairs(out), AugmentConfig(max_width=224), seed=0)
    left, right = sampler.next_batch(8)  # decodes every image it draws, size-checked
    assert left.shape == right.shape == (8, 1, 48, 160)
