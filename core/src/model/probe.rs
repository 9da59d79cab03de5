//! Observing intermediate stages of a run (host validation against the float model).

/// A point in the encoder where the residual stream is complete for every token.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// After patch embedding and the row embedding: residual format 0.
    Embed,
    /// After block `b`'s attention half: residual format `2b + 1`.
    Attention(usize),
    /// After block `b` (attention and MLP): residual format `2b + 2`.
    Block(usize),
}

impl Stage {
    /// The residual format the stage's codes are in.
    pub const fn residual_format(self) -> usize {
        match self {
            Stage::Embed => 0,
            Stage::Attention(b) => 2 * b + 1,
            Stage::Block(b) => 2 * b + 2,
        }
    }
}

/// Receives the residual stream (`rows x fused columns x DIM` int8 codes) at each [`Stage`].
pub trait Probe {
    /// Called once per stage; the default does nothing.
    fn observe(&mut self, stage: Stage, rows: usize, fused_cols: usize, codes: &[i8]) {
        let _ = (stage, rows, fused_cols, codes);
    }
}

/// A probe that ignores everything: what firmware and plain inference use.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProbe;

impl Probe for NoProbe {}
