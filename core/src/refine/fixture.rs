//! Reader of the refinement fixtures the Python writes (`bino_train.refine.write_fixture`'s
//! format), shared by the tests that pin `refine_map` and `refine_map_equalised` to it: a
//! 4-byte magic, the case count (`u16`), then per case `h, w, census_radius, search, lambda,
//! box_radius` (`u16` each), the left and right views (`h w` bytes each), the token grid
//! (`ceil(h / 4) ceil(w / 4)` `u16`) and the expected pixels (`h w` `u16`), little-endian.

use super::RefineParams;

/// One case of a fixture.
pub(crate) struct Case<'f> {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// The refinement's parameters.
    pub params: RefineParams,
    /// Left view, `height * width` bytes.
    pub left: &'f [u8],
    /// Right view.
    pub right: &'f [u8],
    tokens: &'f [u8],
    expected: &'f [u8],
}

fn u16_at(bytes: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]])
}

impl Case<'_> {
    /// Token cells of the case's grid.
    pub fn cells(&self) -> usize {
        self.height.div_ceil(4) * self.width.div_ceil(4)
    }

    /// The token grid into `out` (at least [`Self::cells`] long); returns that prefix.
    pub fn tokens<'o>(&self, out: &'o mut [u16]) -> &'o [u16] {
        let cells = self.cells();
        for (i, t) in out[..cells].iter_mut().enumerate() {
            *t = u16_at(self.tokens, i);
        }
        &out[..cells]
    }

    /// Asserts that `found` (`height * width` pixels) is the expected refinement, naming the
    /// case and the first pixel that differs.
    pub fn check(&self, case: usize, found: &[u16]) {
        assert_eq!(found.len(), self.height * self.width, "case {case}");
        for (i, &f) in found.iter().enumerate() {
            let expected = u16_at(self.expected, i);
            let (y, x) = (i / self.width, i % self.width);
            assert_eq!(f, expected, "case {case} ({:?}): pixel ({y}, {x})", self.params);
        }
    }
}

/// Calls `each` with every case of `fixture` (whose first bytes must be `magic`) in order, and
/// checks that the cases fill the file exactly; returns the case count.
pub(crate) fn for_each_case(fixture: &[u8], magic: &[u8; 4], mut each: impl FnMut(usize, Case<'_>)) -> usize {
    assert_eq!(&fixture[..4], magic, "the fixture's magic");
    let cases = u16_at(&fixture[4..6], 0) as usize;
    let mut at = 6;
    for case in 0..cases {
        let f: [usize; 6] = core::array::from_fn(|i| u16_at(&fixture[at..], i) as usize);
        at += 12;
        let (height, width) = (f[0], f[1]);
        let n = height * width;
        let cells = height.div_ceil(4) * width.div_ceil(4);
        let take = |at: &mut usize, len: usize| {
            let s = &fixture[*at..*at + len];
            *at += len;
            s
        };
        let left = take(&mut at, n);
        let right = take(&mut at, n);
        let tokens = take(&mut at, 2 * cells);
        let expected = take(&mut at, 2 * n);
        let params = RefineParams {
            census_radius: f[2],
            search: f[3],
            lambda: f[4] as u32,
            box_radius: f[5],
        };
        each(
            case,
            Case {
                height,
                width,
                params,
                left,
                right,
                tokens,
                expected,
            },
        );
    }
    assert_eq!(at, fixture.len(), "the cases fill the fixture");
    cases
}
