//! `cnfmp doctor`: is this machine ready? Starts the embedded interpreter on the project venv
//! and reports it, the pinned packages, torch's threads, a MuJoCo test render (and its GL
//! backend), and a zero-copy array round trip through the bridge. Fails with a one-line fix.

use segmenter_bridge::ndarray::{ArrayD, IxDyn};
use segmenter_bridge::{Bridge, DoctorCheck, DoctorReport};

use super::print_stdout;
use crate::failure::Failure;

pub fn run(json: bool) -> Result<(), Failure> {
    let bridge = Bridge::start_default()?;
    let mut report = bridge.doctor()?;
    report.checks.push(zero_copy_check(bridge));
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
    text
}
