//! The BINO model configuration (DESIGN.md, paper section 3): fixed at compile time.

/// Channels of the token stream.
pub const DIM: usize = 128;
/// Transformer blocks.
pub const DEPTH: usize = 7;
/// Attention heads.
pub const HEADS: usize = 4;
/// Channels per head.
pub const HEAD_DIM: usize = DIM / HEADS;
/// Hidden width of each block's MLP.
pub const MLP_HIDDEN: usize = 480;
/// Image channels the model takes (grayscale replicated to three).
pub const IN_CHANS: usize = 3;
/// Patch height on the fused image, in pixels.
pub const PATCH_H: usize = 4;
/// Patch width on the fused image (2 columns of each view: a 4x2 stereo micro-cell).
pub const PATCH_W: usize = 4;
/// View pixels per patch column: its two phase tokens cover 2 view columns each.
pub const CELL_W: usize = PATCH_W;
/// Image rows the encoder sees at once.
pub const BAND_ROWS: usize = 48;
/// Token rows per band, and the size of the learnable row-embedding table.
pub const BAND_TOKEN_ROWS: usize = BAND_ROWS / PATCH_H;
/// Token rows between the starts of consecutive bands of a tall image.
pub const BAND_STRIDE_TOKEN_ROWS: usize = 8;
/// Tallest image the engine takes, in pixels (65,536 rows, far beyond any sensor). The bound
/// keeps every row and band index, and every product of them, far inside `usize` on 32-bit
/// cores, so no band plan or row count can wrap.
pub const MAX_HEIGHT: usize = 1 << 16;
/// [`MAX_HEIGHT`] in token rows.
pub const MAX_TOKEN_ROWS: usize = MAX_HEIGHT / PATCH_H;

/// Channels of the shared head's L/R projection.
pub const HEAD_PROJ_DIM: usize = 96;
/// Projection channels of the native pathway's head (`P_L`, `P_R`; 96 would put it over 15 %
/// of an encoder pass in MACs at 48x160, `train/bino_train/head.py`, `NATIVE_HEAD`).
pub const NATIVE_HEAD_PROJ_DIM: usize = 64;
/// Groups of the head's groupwise correlation.
pub const HEAD_GROUPS: usize = 16;
/// Channels of the head's 3D regularisation net.
pub const HEAD_HIDDEN: usize = 24;
/// Residual 3D convolutions between the head's stem and output.
pub const HEAD_MIDDLE_LAYERS: usize = 4;
/// Disparity candidates the heads were trained with, in patch columns (`0..HEAD_MAX_DISP`), and
/// their default count. A head stream may search more (`HeadStream::with_candidates`, up to
/// [`HEAD_CANDIDATES_LIMIT`]): no weight depends on the count, since the correlation and the 3D
/// convolutions slide along the disparity axis.
pub const HEAD_MAX_DISP: usize = 12;
/// The most disparity candidates a head stream searches (the row matchers' limit too).
pub const HEAD_CANDIDATES_LIMIT: usize = 64;

/// Disparity candidates of the heads for views `width` px wide, in patch columns: the
/// StereoSGBM reference's search range at that width (EVAL.md: `numDisparities` 32 px per
/// 160 px of width, 64 px = 16 columns at w320), never fewer than the [`HEAD_MAX_DISP`] = 12
/// they were trained with and at most [`HEAD_CANDIDATES_LIMIT`]. The host's commands and the
/// board presets at a width ([`crate::preset::options_for_width`]) use it, so a readout has one
/// definition per width.
pub const fn head_candidates(width: usize) -> usize {
    let sgbm_px = 16 * width.saturating_mul(2).div_ceil(160);
    let candidates = sgbm_px / CELL_W;
    if candidates < HEAD_MAX_DISP {
        HEAD_MAX_DISP
    } else if candidates > HEAD_CANDIDATES_LIMIT {
        HEAD_CANDIDATES_LIMIT
    } else {
        candidates
    }
}

/// Token-grid size of a `height` x `width` view: (token rows, patch columns, fused columns).
pub const fn token_grid(height: usize, width: usize) -> (usize, usize, usize) {
    (height / PATCH_H, width / CELL_W, 2 * (width / CELL_W))
}

/// Checks that a view size fits the token grid and is at most [`MAX_HEIGHT`] rows; returns
/// (token rows, patch columns). The width's limit is the blob's ([`crate::Error::TooWide`]).
pub fn check_view_size(height: usize, width: usize) -> Result<(usize, usize), crate::Error> {
    if height == 0 || width == 0 {
        return Err(crate::Error::EmptyImage);
    }
    if height > MAX_HEIGHT {
        return Err(crate::Error::TooTall {
            height,
            max: MAX_HEIGHT,
        });
    }
    if !height.is_multiple_of(PATCH_H) {
        return Err(crate::Error::NotMultiple {
            what: "height",
            value: height,
            multiple: PATCH_H,
        });
    }
    if !width.is_multiple_of(CELL_W) {
        return Err(crate::Error::NotMultiple {
            what: "width",
            value: width,
            multiple: CELL_W,
        });
    }
    Ok((height / PATCH_H, width / CELL_W))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_of_paper_band() {
        assert_eq!(token_grid(48, 160), (12, 40, 80));
        assert_eq!(check_view_size(48, 160), Ok((12, 40)));
    }

    #[test]
    fn rejects_sizes_off_the_grid() {
        assert_eq!(check_view_size(0, 8), Err(crate::Error::EmptyImage));
        assert!(matches!(
            check_view_size(50, 8),
            Err(crate::Error::NotMultiple { what: "height", .. })
        ));
        assert!(matches!(
            check_view_size(48, 10),
            Err(crate::Error::NotMultiple { what: "width", .. })
        ));
        assert_eq!(check_view_size(MAX_HEIGHT, 8), Ok((MAX_TOKEN_ROWS, 2)));
        assert_eq!(
            check_view_size(MAX_HEIGHT + 4, 8),
            Err(crate::Error::TooTall {
                height: MAX_HEIGHT + 4,
                max: MAX_HEIGHT
            })
        );
    }
}
