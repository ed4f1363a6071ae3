//! The `--helper-processes` flag of the commands that predict many scenes (`serve`, `eval`):
//! more Python interpreters that fit a scene's objects beside the embedded one, one core
//! each (threads of one interpreter wait on each other between the fit's small torch calls;
//! see `cnfmp.helper_processes`).

use clap::Args;
use segmenter_bridge::Bridge;

use crate::failure::Failure;

#[derive(Debug, Clone, Args)]
pub struct HelperArgs {
    /// Helper processes that fit objects beside the main interpreter, one core each (about
    /// 300 MiB and a few seconds of start-up each). Default: one per core the process may use
    /// beyond the first (CNFMP_INFERENCE_THREADS, when set, is the number of cores); 0 fits
    /// everything in this process.
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=64))]
    pub helper_processes: Option<u32>,
}

impl HelperArgs {
    /// Starts the helpers (before the models are loaded and warmed up, so the warm-ups reach
    /// them too) and says how many run on stderr, prefixed by `command`.
    pub fn start(&self, bridge: &Bridge, command: &str) -> Result<u32, Failure> {
        let count = bridge
            .core_start_helpers(self.helper_processes)
            .map_err(|err| Failure::from(err).with_context("cannot start the helper processes"))?;
        if count > 0 {
            eprintln!("{command}: {count} helper process(es) fit objects beside the main interpreter");
        }
        Ok(count)
    }
}
