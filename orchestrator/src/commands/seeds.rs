//! Scene seeds: which are for training, validation and held-out evaluation. Datasets number
//! their demonstrations from 0; every command that evaluates checks its seeds here, so the
//! ranges cannot drift apart between commands.

use crate::failure::Failure;

/// First held-out scene seed (seeds below it are for training; see `cnfmp sim`).
pub const FIRST_HELDOUT_SEED: u64 = 1_000_000;
/// First validation scene seed: the upper half of the training range, far above any
/// dataset's demonstrations (which number from 0). The validation scripts under `scripts/`
/// start at the same seed (`VALIDATION_SEED_START` in `python/cnfmp/core/trial.py`).
pub const FIRST_VALIDATION_SEED: u64 = 500_000;
/// One past the last held-out seed.
pub const HELDOUT_SEED_END: u64 = 2_000_000;

/// The last seed of `episodes` consecutive scenes from `seed_start`, all of which must be
/// held-out; a bad-input failure otherwise.
pub(crate) fn heldout_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        FIRST_HELDOUT_SEED..HELDOUT_SEED_END,
        "evaluation scenes must be held-out",
    )
}

/// The last seed of `episodes` consecutive validation scenes from `seed_start`: training-range
/// seeds from FIRST_VALIDATION_SEED, which no dataset of demonstrations reaches; a bad-input
/// failure otherwise.
pub(crate) fn validation_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        FIRST_VALIDATION_SEED..FIRST_HELDOUT_SEED,
        "validation scenes must be training-range seeds no demonstration uses",
    )
}

/// The last of `episodes` consecutive seeds from `seed_start` when all lie in `allowed`; else
/// a bad-input failure that starts with `rule`.
fn seeds_within(
    seed_start: u64,
    episodes: u64,
    allowed: std::ops::Range<u64>,
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
    use super::{FIRST_HELDOUT_SEED, heldout_seed_range, validation_seed_range};

    #[test]
    fn validation_and_held_out_seed_ranges_do_not_overlap() {
        assert_eq!(validation_seed_range(500_000, 80).unwrap(), 500_079);
        assert_eq!(validation_seed_range(999_990, 10).unwrap(), 999_999);
        assert!(validation_seed_range(499_999, 1).is_err()); // too close to the demonstrations
        assert!(validation_seed_range(999_999, 2).is_err()); // runs into the held-out seeds
        assert!(validation_seed_range(FIRST_HELDOUT_SEED, 1).is_err());
        assert!(heldout_seed_range(999_999, 1).is_err());
        assert_eq!(heldout_seed_range(FIRST_HELDOUT_SEED, 50).unwrap(), FIRST_HELDOUT_SEED + 49);
    }
}
