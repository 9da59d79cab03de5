# Shared locations for the project's scripts (sourced, not run).
# Build outputs and the Python environment live outside the clone, so CI runs on the same
# machine reuse them: tract-onnx takes ~12 minutes to build from scratch on 2 cores and
# torch is a ~3 GB download.
BINO_CACHE="${BINO_CACHE:-$HOME/.cache/bino-edge}"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$BINO_CACHE/target}"
export BINO_VENV="${BINO_VENV:-$BINO_CACHE/venv}"
BINO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export BINO_ROOT
THUMB_TARGETS="thumbv7em-none-eabihf thumbv8m.main-none-eabihf"
