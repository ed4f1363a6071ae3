//! `cnfmp doctor`: is this machine ready? Starts the embedded interpreter on the project venv
//! and reports it, the pinned packages, torch's threads, a MuJoCo test render (and its GL
//! backend), a zero-copy array round trip through the bridge, and what a cold start costs
//! (imports, the segmenter, with `--model` that model's load and first prediction). Fails
//! with a one-line fix.

use std::path::PathBuf;

use clap::Args;
use segmenter_bridge::ndarray::{ArrayD, IxDyn};
use segmenter_bridge::{Bridge, BridgeError, DoctorCheck, DoctorReport};

use super::print_stdout;
use crate::failure::Failure;

#[derive(Debug, Args)]
pub struct DoctorArgs {
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Also time loading this model directory and predicting a synthetic scene with it, first
    /// and warm, in a fresh interpreter (what a cold `cnfmp predict` pays).
    #[arg(long)]
    model: Option<PathBuf>,
}

pub fn run(args: DoctorArgs) -> Result<(), Failure> {
    if let Some(model) = &args.model
        && !model.join("config.json").is_file()
    {
        return Err(Failure::BadInput(format!("--model {} is not a model directory (no config.json)", model.display())));
    }
    let json = args.json;
    let bridge = Bridge::start_default()?;
    let mut report = bridge.doctor()?;
    report.checks.push(zero_copy_check(bridge));
    match bridge.startup_costs(args.model.as_deref()) {
        Ok(startup) => report.startup = Some(startup),
        Err(BridgeError::InvalidInput(why)) => report.checks.push(DoctorCheck {
            name: "start-up probe".into(),
            ok: false,
            detail: why,
            fix: "run `cnfmp predict` on one scene to see the full error".into(),
            backend: None,
        }),
        Err(other) => return Err(other.into()),
    }
    if json {
        print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
    } else {
        print_stdout(&render_report(&report))?;
    }
    match report.checks.iter().find(|check| !check.ok) {
        None => Ok(()),
        Some(first) => {
            let failed = report.checks.iter().filter(|check| !check.ok).count();
            Err(Failure::Environment(format!("{failed} check(s) failed, first `{}`; fix: {}", first.name, first.fix)))
        }
    }
}

fn zero_copy_check(bridge: &Bridge) -> DoctorCheck {
    let values = ArrayD::from_shape_fn(IxDyn(&[2, 3]), |ix| (ix[0] * 3 + ix[1]) as f64);
    let expected = values.mapv(|v| 2.0 * v);
    let (ok, detail) = match bridge.array_round_trip(values) {
        Ok(trip) if trip.same_buffer && trip.values == expected => (true, "2x3 float64 array changed in place by Python, same buffer".to_owned()),
        Ok(trip) => (false, format!("same buffer: {}, values right: {}", trip.same_buffer, trip.values == expected)),
        Err(err) => (false, err.to_string()),
    };
    DoctorCheck { name: "bridge zero-copy".into(), ok, detail, fix: if ok { String::new() } else { "report a bug: numpy arrays must cross the bridge without copies".into() }, backend: None }
}

fn render_report(report: &DoctorReport) -> String {
    let python = &report.python;
    let mut text = format!("embedded Python {} (sys.prefix {})", python.version, python.prefix);
    for check in &report.checks {
        text += &format!("\n{} {:<24} {}", if check.ok { "ok  " } else { "FAIL" }, check.name, check.detail);
        if !check.fix.is_empty() {
            text += &format!("\n     fix: {}", check.fix);
        }
    }
    if let Some(startup) = &report.startup {
        text += "\ncold start, timed in a fresh interpreter:";
        for stage in &startup.stages {
            text += &format!("\n     {:<28} {:>7.0} ms", stage.name, stage.ms);
        }
        text += &format!("\n     {:<28} {:>7.0} ms (interpreter start and exit included)", "whole process", startup.process_ms);
        if !startup.stages.iter().any(|stage| stage.name == "load the model") {
            text += "\n     (give --model DIR to time loading a model and its first prediction)";
        }
    }
    text
}
