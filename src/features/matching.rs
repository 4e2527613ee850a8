//! Correspondences from descriptors: pairs that are each other's nearest neighbour in
//! descriptor space (no ratio or distance threshold to tune). Brute force: at a few thousand
//! keypoints a scan of 33 bins per pair is a fraction of a second and needs no index.

use super::fpfh::Fpfh;
use crate::parallel::Workers;

/// Keypoints per parallel chunk (each scans every keypoint of the other cloud).
const CHUNK: usize = 32;

/// The pairs (i, j) where `target[j]` is the nearest of the target descriptors to `source[i]`
/// and `source[i]` the nearest of the source descriptors to `target[j]`, in ascending i.
/// Descriptors that are all zero (no neighbours) take no part.
pub fn mutual_matches(source: &[Fpfh], target: &[Fpfh], workers: &Workers) -> Vec<(usize, usize)> {
    let forward = nearest_of_each(source, target, workers);
    let backward = nearest_of_each(target, source, workers);
    forward
        .iter()
        .enumerate()
        .filter_map(|(i, &j)| {
            let j = j?;
            (backward[j] == Some(i)).then_some((i, j))
        })
        .collect()
}

/// For each of `queries`, the index of its nearest in `candidates` (`None` for an empty
/// descriptor or no candidate).
fn nearest_of_each(queries: &[Fpfh], candidates: &[Fpfh], workers: &Workers) -> Vec<Option<usize>> {
    let usable = |f: &Fpfh| f.iter().any(|&v| v != 0.0);
    let usable_candidates: Vec<usize> = (0..candidates.len())
        .filter(|&j| usable(&candidates[j]))
        .collect();
    let mut nearest = vec![None; queries.len()];
    workers.for_each_chunk_of(CHUNK, &mut nearest, |first, piece| {
        for (offset, slot) in piece.iter_mut().enumerate() {
            let query = &queries[first + offset];
            if !usable(query) {
                continue;
            }
            let mut best = (None, f64::INFINITY);
            for &j in &usable_candidates {
                let d = squared_distance(query, &candidates[j], best.1);
                if d < best.1 {
                    best = (Some(j), d);
                }
            }
            *slot = best.0;
        }
    });
    nearest
}

/// Squared Euclidean distance, stopping early once it passes `bound` (then any value ≥ bound).
#[inline]
fn squared_distance(a: &Fpfh, b: &Fpfh, bound: f64) -> f64 {
    let mut sum = 0.0;
    for (part_a, part_b) in a.chunks_exact(11).zip(b.chunks_exact(11)) {
        sum += part_a
            .iter()
            .zip(part_b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>();
        if sum >= bound {
            return sum;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
