//! Correspondences from descriptors: pairs that are each other's nearest neighbour in
//! descriptor space (no ratio or distance threshold to tune). Brute force: at a few thousand
//! keypoints a scan of 33 bins per pair is a fraction of a second and needs no index.
//!
//! Each distance is computed once and serves both directions: a source's nearest target is the
//! minimum along its row, a target's nearest source the minimum down its column. The targets
//! are stored in blocks of [`LANES`], bin by bin, so that one source's differences to a block
//! run side by side (vectorised) with each lane summing in the order of a plain scalar loop:
//! the distances, and so the matches, are those of the straightforward two-way scan. A block is
//! left early once no lane can beat its row's or its column's best so far.

use super::fpfh::{FPFH_BINS, Fpfh};
use crate::parallel::Workers;

/// Targets compared with one source at a time.
const LANES: usize = 8;
/// Bins summed before each partial sum is added to the total (the scalar loop's grouping).
const BINS_PER_PART: usize = 11;
/// Source descriptors per parallel piece (each is compared with every target).
const BAND: usize = 256;

/// The pairs (i, j) where `target[j]` is the nearest of the target descriptors to `source[i]`
/// and `source[i]` the nearest of the source descriptors to `target[j]`, in ascending i. Ties go
/// to the lower index. Descriptors that are all zero (no neighbours) take no part.
pub fn mutual_matches(source: &[Fpfh], target: &[Fpfh], workers: &Workers) -> Vec<(usize, usize)> {
    let blocks = TargetBlocks::of(target);
    let usable_sources: Vec<usize> = (0..source.len()).filter(|&i| usable(&source[i])).collect();
    let mut bands: Vec<Band> = usable_sources
        .chunks(BAND)
        .map(|sources| Band {
            sources: sources.to_vec(),
            nearest_target: Vec::new(),
            nearest_source: Vec::new(),
        })
        .collect();
    workers.for_each_chunk_of(1, &mut bands, |_, piece| {
        for band in piece {
            band.scan(source, &blocks, target.len());
        }
    });
    // A target's nearest source over all bands: bands run in ascending source order, so a tie
    // keeps the earlier (lower) source.
    let mut nearest_source = vec![(f64::INFINITY, usize::MAX); target.len()];
    for band in &bands {
        for (best, &candidate) in nearest_source.iter_mut().zip(&band.nearest_source) {
            if candidate.0 < best.0 {
                *best = candidate;
            }
        }
    }
    bands
        .iter()
        .flat_map(|band| band.sources.iter().zip(&band.nearest_target))
        .filter_map(|(&i, &j)| {
            let j = j?;
            (nearest_source[j].1 == i).then_some((i, j))
        })
        .collect()
}

fn usable(f: &Fpfh) -> bool {
    f.iter().any(|&v| v != 0.0)
}

/// The usable targets, [`LANES`] to a block, each block stored bin by bin.
struct TargetBlocks {
    bins: Vec<[[f64; LANES]; FPFH_BINS]>,
    /// The target index in each lane (`None`: padding at the end).
    ids: Vec<[Option<usize>; LANES]>,
}

impl TargetBlocks {
    fn of(target: &[Fpfh]) -> Self {
        let usable_targets: Vec<usize> = (0..target.len()).filter(|&j| usable(&target[j])).collect();
        let mut bins = Vec::with_capacity(usable_targets.len().div_ceil(LANES));
        let mut ids = Vec::with_capacity(bins.capacity());
        for group in usable_targets.chunks(LANES) {
            // Padding lanes are infinitely far: never nearer than anything.
            let mut block = [[f64::INFINITY; LANES]; FPFH_BINS];
            let mut lane_ids = [None; LANES];
            for (lane, &j) in group.iter().enumerate() {
                lane_ids[lane] = Some(j);
                for (bin, value) in target[j].iter().enumerate() {
                    block[bin][lane] = *value;
                }
            }
            bins.push(block);
            ids.push(lane_ids);
        }
        TargetBlocks { bins, ids }
    }
}

/// Consecutive usable sources and, once scanned, each one's nearest target and each target's
/// nearest among them.
struct Band {
    sources: Vec<usize>,
    nearest_target: Vec<Option<usize>>,
    /// Per target: (squared distance, source index); (∞, usize::MAX) when none is nearer.
    nearest_source: Vec<(f64, usize)>,
}

impl Band {
    fn scan(&mut self, source: &[Fpfh], blocks: &TargetBlocks, targets: usize) {
        self.nearest_source = vec![(f64::INFINITY, usize::MAX); targets];
        self.nearest_target = Vec::with_capacity(self.sources.len());
        for &i in &self.sources {
            let mut best = (None, f64::INFINITY);
            for (block, ids) in blocks.bins.iter().zip(&blocks.ids) {
                // A lane whose first parts already reach both its row's and its column's best
                // cannot win either (the parts only add): a block of such lanes is left there.
                let mut bounds = [f64::INFINITY; LANES];
                for (bound, id) in bounds.iter_mut().zip(ids) {
                    if let Some(j) = id {
                        *bound = best.1.max(self.nearest_source[*j].0);
                    }
                }
                let Some(distances) = squared_distances(&source[i], block, &bounds) else {
                    continue;
                };
                for (lane, &id) in ids.iter().enumerate() {
                    let Some(j) = id else { continue };
                    let d = distances[lane];
                    if d < best.1 {
                        best = (Some(j), d);
                    }
                    if d < self.nearest_source[j].0 {
                        self.nearest_source[j] = (d, i);
                    }
                }
            }
            self.nearest_target.push(best.0);
        }
    }
}

/// Squared Euclidean distances from `query` to the block's lanes, each summed as
/// Σ_parts (Σ_bins in part (q − t)²) in bin order; `None` as soon as, after a part, every lane
/// is at or beyond its bound.
#[inline]
fn squared_distances(
    query: &Fpfh,
    block: &[[f64; LANES]; FPFH_BINS],
    bounds: &[f64; LANES],
) -> Option<[f64; LANES]> {
    let mut total = [0.0; LANES];
    for (query_part, block_part) in query
        .chunks_exact(BINS_PER_PART)
        .zip(block.chunks_exact(BINS_PER_PART))
    {
        let mut part = [0.0; LANES];
        for (&q, lanes) in query_part.iter().zip(block_part) {
            for lane in 0..LANES {
                let d = q - lanes[lane];
                part[lane] += d * d;
            }
        }
        for lane in 0..LANES {
            total[lane] += part[lane];
        }
        if total.iter().zip(bounds).all(|(t, b)| t >= b) {
            return None;
        }
    }
    Some(total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn only_pairs_that_choose_each_other_are_kept() {
        let f = |v: f64| {
            let mut x = [0.0; 33];
            x[0] = v;
            x
        };
        let source = [f(1.0), f(2.0), f(10.0), [0.0; 33]];
        let target = [f(1.1), f(9.0), f(2.05)];
        let workers = Workers::new(2).unwrap();
        // 1.0↔1.1 and 2.0↔2.05 choose each other; 10.0 → 9.0, whose nearest is 10.0 too.
        assert_eq!(
            mutual_matches(&source, &target, &workers),
            vec![(0, 0), (1, 2), (2, 1)]
        );
    }

    /// The nearest of `candidates` to each query by a plain scalar scan (first index on ties).
    fn plain_nearest(queries: &[Fpfh], candidates: &[Fpfh]) -> Vec<Option<usize>> {
        queries
            .iter()
            .map(|q| {
                if !usable(q) {
                    return None;
                }
                let mut best = (None, f64::INFINITY);
                for (j, c) in candidates.iter().enumerate().filter(|(_, c)| usable(c)) {
                    let d: f64 = q
                        .chunks_exact(BINS_PER_PART)
                        .zip(c.chunks_exact(BINS_PER_PART))
                        .map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>())
                        .fold(0.0, |sum, part| sum + part);
                    if d < best.1 {
                        best = (Some(j), d);
                    }
                }
                best.0
            })
            .collect()
    }

    #[test]
    fn the_one_pass_scan_finds_the_plain_two_way_scans_pairs_ties_included() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(31);
        // Coarse values make equal distances (ties) common; some descriptors are empty, and the
        // counts are not multiples of the lanes or bands.
        let descriptor = |rng: &mut Xoshiro256PlusPlus| -> Fpfh {
            let mut f = [0.0; FPFH_BINS];
            if rng.random_range(0..20) > 0 {
                for v in f.iter_mut() {
                    *v = f64::from(rng.random_range(0..4u8)) * 0.5;
                }
            }
            f
        };
        let source: Vec<Fpfh> = (0..203).map(|_| descriptor(&mut rng)).collect();
        let target: Vec<Fpfh> = (0..150).map(|_| descriptor(&mut rng)).collect();
        let forward = plain_nearest(&source, &target);
        let backward = plain_nearest(&target, &source);
        let expected: Vec<(usize, usize)> = forward
            .iter()
            .enumerate()
            .filter_map(|(i, &j)| (backward[j?] == Some(i)).then_some((i, j?)))
            .collect();
        assert!(
            expected.len() > 10,
            "the case must have mutual pairs: {}",
            expected.len()
        );
        for threads in [1, 2, 3] {
            let workers = Workers::new(threads).unwrap();
            assert_eq!(
                mutual_matches(&source, &target, &workers),
                expected,
                "{threads} threads"
            );
        }
    }
}
