//! The paper's Table I as a benchmark: its tasks and training-set sizes, its method rows and
//! published figures.

use crate::seeds::SEEDS;

/// The Table-I tasks, in the paper's column order.
pub(super) const TASKS: [&str; 4] = ["wall_avoidance", "incline_pick_place", "cup_stacking", "cube_stacking"];
/// Training-set sizes (low, high regime) per task, as in the paper.
pub(super) const SIZES: [(usize, usize); 4] = [(10, 30), (20, 50), (20, 50), (30, 100)];
/// Sizes of --quick.
pub(super) const QUICK_SIZES: (usize, usize) = (3, 5);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Regime {
    Low,
    High,
    /// The NFMP grid: training scenes laid out as a parameter grid (`python/cnfmp/seeds.json`).
    Grid,
}

/// A row of the table: a model type trained on one regime's demonstrations.
pub(super) struct Method {
    /// Row label in the paper's wording.
    pub label: &'static str,
    /// File-name key of the row.
    pub key: &'static str,
    pub model_type: &'static str,
    pub regime: Regime,
}

impl Method {
    /// The tasks the row is evaluated on: every Table-I task, or the grid's task alone (the
    /// paper reports NFMP on its grid task only).
    pub(super) fn tasks(&self) -> Vec<&'static str> {
        match self.regime {
            Regime::Grid => vec![SEEDS.nfmp_grid.task.as_str()],
            Regime::Low | Regime::High => TASKS.to_vec(),
        }
    }

    /// How many demonstrations of `task` the row trains on, and the first training seed.
    pub(super) fn demonstrations(&self, task: &str, quick: bool) -> (usize, u64) {
        let sizes = || if quick { QUICK_SIZES } else { SIZES[TASKS.iter().position(|t| *t == task).expect("a Table-I task")] };
        match self.regime {
            Regime::Low => (sizes().0, SEEDS.training.start),
            Regime::High => (sizes().1, SEEDS.training.start),
            Regime::Grid => {
                let grid = &SEEDS.nfmp_grid.seeds;
                ((grid.end - grid.start) as usize, grid.start)
            }
        }
    }
}

pub(super) const METHODS: [Method; 5] = [
    Method { label: "CNN-CNMP (low)", key: "cnn-cnmp-low", model_type: "cnn-cnmp", regime: Regime::Low },
    Method { label: "CNN-CNMP (high)", key: "cnn-cnmp-high", model_type: "cnn-cnmp", regime: Regime::High },
    Method { label: "NFMP (grid)", key: "nfmp-grid", model_type: "nfmp", regime: Regime::Grid },
    Method { label: "ours without gating (low)", key: "cnfmp-nogate-low", model_type: "cnfmp-nogate", regime: Regime::Low },
    Method { label: "ours (low)", key: "cnfmp-low", model_type: "cnfmp", regime: Regime::Low },
];

/// The paper's Table I (MED cm, success), per method row and task; None where not reported.
pub(super) const PAPER: [[Option<(f64, f64)>; 4]; 5] = [
    [Some((2.66, 0.63)), Some((3.98, 0.11)), Some((9.03, 0.03)), Some((13.44, 0.00))],
    [Some((1.33, 0.97)), Some((2.12, 0.68)), Some((2.81, 0.23)), Some((5.87, 0.00))],
    [Some((0.65, 0.99)), None, None, None],
    [Some((0.66, 1.00)), Some((0.85, 1.00)), Some((1.06, 0.81)), Some((1.39, 0.79))],
    [Some((0.48, 1.00)), Some((0.73, 1.00)), Some((0.60, 1.00)), Some((0.66, 0.97))],
];
