//! The inlier test and the support count of a motion over all pairs, a block of pairs at a time.

use super::fit_rigid;
use crate::math::{Iso2, Vec2};

/// Pairs per block of the inlier test.
const BLOCK: usize = 64;

/// The pairs as columns (source x, y, target x, y, squared radius): the inlier test runs branch-free
/// over a block of pairs at a time (it vectorises), and only the pairs it marks are visited.
///
/// The test runs in f32 (twice the vector width of f64): the coordinates are taken relative to the
/// pairs' centroids, so a submap's tens to hundreds of metres keep about 10 micrometres of
/// resolution, far below any inlier radius; the motion's translation is re-expressed for them.
pub(super) struct Columns {
    sx: Vec<f32>,
    sy: Vec<f32>,
    tx: Vec<f32>,
    ty: Vec<f32>,
    thr2: Vec<f32>,
    /// The centroids subtracted from the source and target coordinates.
    source_centre: Vec2,
    target_centre: Vec2,
    /// The full-precision coordinates, for the least-squares fits.
    xs: Vec<Vec2>,
    ys: Vec<Vec2>,
}

impl Columns {
    /// The columns of the pairs `xs[k] -> ys[k]` with squared radii `thr2[k]`.
    pub(super) fn new(xs: &[Vec2], ys: &[Vec2], thr2: &[f64]) -> Self {
        let centre = |v: &[Vec2]| v.iter().sum::<Vec2>() / v.len().max(1) as f64;
        let (cs, ct) = (centre(xs), centre(ys));
        Columns {
            sx: xs.iter().map(|p| (p.x - cs.x) as f32).collect(),
            sy: xs.iter().map(|p| (p.y - cs.y) as f32).collect(),
            tx: ys.iter().map(|p| (p.x - ct.x) as f32).collect(),
            ty: ys.iter().map(|p| (p.y - ct.y) as f32).collect(),
            thr2: thr2.iter().map(|&r| r as f32).collect(),
            source_centre: cs,
            target_centre: ct,
            xs: xs.to_vec(),
            ys: ys.to_vec(),
        }
    }

    fn len(&self) -> usize {
        self.sx.len()
    }

    /// Marks (1) in `mask` the pairs `start..start + BLOCK` (fewer at the end) within their radius
    /// under `t`; returns how many pairs the block holds.
    fn block(&self, start: usize, t: &Iso2, mask: &mut [u8; BLOCK]) -> usize {
        // y - (R x + p) with x = x' + cs, y = y' + ct: y' - (R x' + p'), p' = p + R cs - ct.
        let p = t.translation.vector + t.rotation * self.source_centre - self.target_centre;
        let (c, s) = (t.rotation.re as f32, t.rotation.im as f32);
        let (px, py) = (p.x as f32, p.y as f32);
        let end = (start + BLOCK).min(self.len());
        let cols = self.sx[start..end]
            .iter()
            .zip(&self.sy[start..end])
            .zip(&self.tx[start..end])
            .zip(&self.ty[start..end])
            .zip(&self.thr2[start..end]);
        for (m, ((((ax, ay), bx), by), r2)) in mask.iter_mut().zip(cols) {
            let dx = bx - (c * ax - s * ay + px);
            let dy = by - (s * ax + c * ay + py);
            *m = u8::from(dx * dx + dy * dy <= *r2);
        }
        end - start
    }

    /// Indices of the pairs within their radius under `t`, into `out` (cleared first).
    pub(super) fn inliers_into(&self, t: &Iso2, out: &mut Vec<usize>) {
        out.clear();
        let mut mask = [0u8; BLOCK];
        for start in (0..self.len()).step_by(BLOCK) {
            let len = self.block(start, t, &mut mask);
            out.extend((0..len).filter(|&l| mask[l] != 0).map(|l| start + l));
        }
    }

    /// The least-squares rigid motion ([`fit_rigid`]) of the pairs `ids`.
    pub(super) fn fit(&self, ids: &[usize]) -> Option<Iso2> {
        fit_rigid(ids.iter().map(|&k| (self.xs[k], self.ys[k])))
    }
}

/// Scores motions by the source points they explain.
pub(super) struct Scorer<'a> {
    cols: &'a Columns,
    slots: &'a [u32],
    /// Per source slot, the stamp of the last motion that counted it.
    seen: Vec<u32>,
    stamp: u32,
}

impl<'a> Scorer<'a> {
    /// A scorer of the pairs in `cols`, pair `k` explaining source slot `slots[k]` of `n_slots`.
    pub(super) fn new(cols: &'a Columns, slots: &'a [u32], n_slots: usize) -> Self {
        Scorer {
            cols,
            slots,
            seen: vec![0; n_slots],
            stamp: 0,
        }
    }

    /// Source points with a pair within its radius under `t`; stops early (returning at most `bar`)
    /// once `bar` cannot be beaten.
    pub(super) fn count(&mut self, t: &Iso2, bar: usize) -> usize {
        // Stamps run from 1; `seen` starts at 0 and is cleared to 0 when they wrap.
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.seen.iter_mut().for_each(|s| *s = 0);
            self.stamp = 1;
        }
        let n = self.cols.len();
        let mut count = 0usize;
        let mut mask = [0u8; BLOCK];
        for start in (0..n).step_by(BLOCK) {
            let len = self.cols.block(start, t, &mut mask);
            // Visit the marked pairs only (most blocks of a wrong motion mark none).
            let mut bits = mask_bits(&mask, len);
            while bits != 0 {
                let l = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let slot = &mut self.seen[self.slots[start + l] as usize];
                if *slot != self.stamp {
                    *slot = self.stamp;
                    count += 1;
                }
            }
            if bar > 0 && count + (n - start - len) <= bar {
                break;
            }
        }
        count
    }
}

/// The first `len` entries of a 0/1 `mask` as bits (entry `l` -> bit `l`): eight bytes at a time,
/// gathered into one byte by a multiplication (each 0/1 byte lands on its own bit of the top byte).
#[inline]
fn mask_bits(mask: &[u8; BLOCK], len: usize) -> u64 {
    let mut bits = 0u64;
    for (c, chunk) in mask.chunks_exact(8).enumerate() {
        let mut b = [0u8; 8];
        b.copy_from_slice(chunk);
        let x = u64::from_le_bytes(b);
        bits |= (x.wrapping_mul(0x0102_0408_1020_4080) >> 56) << (8 * c);
    }
    if len < BLOCK {
        bits &= (1u64 << len) - 1;
    }
    bits
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The packed bits are the mask's entries, for every pattern of one and two set entries and for
    /// a short last block.
    #[test]
    fn mask_bits_packs_the_mask() {
        let naive = |m: &[u8; BLOCK], len: usize| {
            (0..len)
                .filter(|&l| m[l] != 0)
                .fold(0u64, |b, l| b | (1 << l))
        };
        for a in 0..BLOCK {
            for b in (a..BLOCK).step_by(7) {
                let mut m = [0u8; BLOCK];
                m[a] = 1;
                m[b] = 1;
                for len in [BLOCK, 63, 40, 9, 1] {
                    assert_eq!(mask_bits(&m, len), naive(&m, len), "{a} {b} {len}");
                }
            }
        }
        assert_eq!(mask_bits(&[1; BLOCK], BLOCK), u64::MAX);
    }
}
