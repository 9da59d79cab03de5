"""`python -m bino_train` prints the model summary."""

from .config import EncoderConfig
from .model import BinoEncoder, parameter_count

if __name__ == "__main__":
    cfg = EncoderConfig()
    n = parameter_count(BinoEncoder(cfg))
    print(f"BINO encoder: {n:,} parameters ({n / 1e6:.4f}M), config {cfg.to_dict()}")
