//! `cnfmp dataset generate`: LeRobot v3.0 datasets of scripted expert demonstrations.

use std::path::PathBuf;

use clap::Subcommand;
use segmenter_bridge::Bridge;

use super::print_stdout;
use crate::failure::Failure;

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Simulate expert demonstrations and write them as a LeRobot v3.0 dataset.
    Generate {
        /// Task name (see `cnfmp sim tasks`).
        #[arg(long)]
        task: String,
        /// Number of (successful) episodes.
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        episodes: u64,
        /// First scene seed; episodes use consecutive seeds. Training seeds are
        /// 0..=999999, held-out seeds 1000000..=1999999; a range may not cross the boundary.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output directory; must not exist (datasets are never overwritten).
        #[arg(long)]
        out: PathBuf,
        /// Simulation worker processes.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
        workers: u32,
    },
}

pub fn run(command: DatasetCommand) -> Result<(), Failure> {
    match command {
        DatasetCommand::Generate { task, episodes, seed, out, workers } => {
            if out.exists() {
                return Err(Failure::BadInput(format!("{} already exists; datasets are never overwritten, choose a new --out", out.display())));
            }
            let report = Bridge::start_default()?.dataset_generate(&task, episodes, seed, &out, workers)?;
            print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
        }
    }
    Ok(())
}
