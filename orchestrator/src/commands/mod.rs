//! One module per top-level `cnfmp` subcommand; each exposes `run(args) -> Result<(), Failure>`.

pub mod doctor;
pub mod trajectory;
