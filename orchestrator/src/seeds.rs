//! Scene seeds: which are for training, validation and held-out evaluation. The ranges are
//! `python/cnfmp/seeds.json`, compiled in: the one source that the Python package reads too.
//! Every command that evaluates checks its seeds here.

use std::ops::Range;
use std::sync::LazyLock;

use serde::Deserialize;

use crate::failure::Failure;

/// The seed ranges, `[start, stop)` each.
#[derive(Debug)]
pub struct SeedRanges {
    /// Training scenes and demonstrations (datasets number from its start).
    pub training: Range<u64>,
    /// Validation scenes: the part of `training` that no dataset's demonstrations reach.
    pub validation: Range<u64>,
    /// Held-out scenes, for evaluation only; disjoint from `training`.
    pub heldout: Range<u64>,
    /// The grid-trained NFMP baseline's scenes.
    pub nfmp_grid: NfmpGrid,
}

/// The training scenes of one task laid out as a parameter grid (one per cell).
#[derive(Debug)]
pub struct NfmpGrid {
    pub task: String,
    pub seeds: Range<u64>,
}

/// The ranges of `python/cnfmp/seeds.json` (a unit test checks that it parses and that the
/// ranges keep their promises).
pub static SEEDS: LazyLock<SeedRanges> = LazyLock::new(|| {
    let text = include_str!("../../python/cnfmp/seeds.json");
    let ranges: RangesFile = serde_json::from_str(text).expect("python/cnfmp/seeds.json parses");
    ranges.into()
});

/// First held-out scene seed, the default of every evaluating command.
pub fn first_heldout_seed() -> u64 {
    SEEDS.heldout.start
}

/// seeds.json as written: `[start, stop]` pairs, as Python's `range(*pair)` reads them.
#[derive(Deserialize)]
struct RangesFile {
    training: [u64; 2],
    validation: [u64; 2],
    heldout: [u64; 2],
    nfmp_grid: GridFile,
}

#[derive(Deserialize)]
struct GridFile {
    task: String,
    seeds: [u64; 2],
}

impl From<RangesFile> for SeedRanges {
    fn from(file: RangesFile) -> Self {
        let range = |[start, stop]: [u64; 2]| start..stop;
        SeedRanges {
            training: range(file.training),
            validation: range(file.validation),
            heldout: range(file.heldout),
            nfmp_grid: NfmpGrid { task: file.nfmp_grid.task, seeds: range(file.nfmp_grid.seeds) },
        }
    }
}

/// The last seed of `episodes` consecutive scenes from `seed_start`, all of which must be
/// held-out; a bad-input failure otherwise.
pub fn heldout_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        SEEDS.heldout.clone(),
        "evaluation scenes must be held-out",
    )
}

/// The last seed of `episodes` consecutive validation scenes from `seed_start` (training-range
/// seeds that no dataset of demonstrations reaches); a bad-input failure otherwise.
pub fn validation_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        SEEDS.validation.clone(),
        "validation scenes must be training-range seeds no demonstration uses",
    )
}

/// The last of `episodes` consecutive seeds from `seed_start` when all lie in `allowed`; else
/// a bad-input failure that starts with `rule`.
fn seeds_within(
    seed_start: u64,
    episodes: u64,
    allowed: Range<u64>,
    rule: &str,
) -> Result<u64, Failure> {
    let last = seed_start.saturating_add(episodes.saturating_sub(1));
    if seed_start < allowed.start || last >= allowed.end {
        return Err(Failure::BadInput(format!(
            "{rule}: seeds {seed_start}..={last} are not all within {}..={}",
            allowed.start,
            allowed.end - 1
        )));
    }
    Ok(last)
}

#[cfg(test)]
mod tests {
    use super::{SEEDS, heldout_seed_range, validation_seed_range};

    #[test]
    fn the_seed_ranges_keep_their_promises() {
        let seeds = &*SEEDS;
        assert!(seeds.training.start <= seeds.validation.start && seeds.validation.end <= seeds.training.end);
        assert!(seeds.validation.start > seeds.training.start, "validation must stay clear of the demonstrations");
        assert!(seeds.training.end <= seeds.heldout.start, "held-out seeds must not be training seeds");
        let grid = &seeds.nfmp_grid.seeds;
        assert!(seeds.training.start <= grid.start && grid.end <= seeds.training.end);
        assert!(grid.end <= seeds.validation.start || grid.start >= seeds.validation.end, "grid scenes are not validation scenes");
        assert_eq!(seeds.nfmp_grid.task, "wall_avoidance");
    }

    #[test]
    fn validation_and_held_out_seed_ranges_do_not_overlap() {
        let (validation, heldout) = (SEEDS.validation.clone(), SEEDS.heldout.clone());
        assert_eq!(validation_seed_range(validation.start, 80).unwrap(), validation.start + 79);
        assert_eq!(validation_seed_range(validation.end - 10, 10).unwrap(), validation.end - 1);
        assert!(validation_seed_range(validation.start - 1, 1).is_err()); // too close to the demonstrations
        assert!(validation_seed_range(validation.end - 1, 2).is_err()); // runs past the validation seeds
        assert!(validation_seed_range(heldout.start, 1).is_err());
        assert!(heldout_seed_range(heldout.start - 1, 1).is_err());
        assert_eq!(heldout_seed_range(heldout.start, 50).unwrap(), heldout.start + 49);
    }
}
