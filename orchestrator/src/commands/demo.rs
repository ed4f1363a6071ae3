//! `cnfmp demo` (what `make demo` runs): the main job end to end, the way a lab's robot stack
//! uses cnfmp. It starts `cnfmp serve` with the shipped models on a free loopback port,
//! renders a held-out scene, sends the image and its prompt over HTTP, executes the returned
//! trajectory in the simulator, prints the stages' timings and the verdict, writes an
//! overlay picture and the trajectory, and stops the server with SIGTERM.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use base64::Engine;
use clap::Args;
use segmenter_bridge::Bridge;
use serde_json::{Map, Value};

use super::print_stdout;
use crate::episode::Simulator;
use crate::failure::Failure;
use crate::seeds::{first_heldout_seed, heldout_seed_range};
use crate::files::write_atomically;
use crate::serve::LISTENING;
use crate::serve::api::{ErrorResponse, TrajectoryResponse};
use crate::trajectory::Trajectory;

/// How long the server may take to load Python, torch and the models.
const SERVER_START_TIMEOUT: Duration = Duration::from_secs(300);

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Task of the scene; its model must be promptable (language_pick_place, wall_avoidance,
    /// incline_pick_place).
    #[arg(long, default_value = "language_pick_place")]
    task: String,
    /// Held-out scene seed (1000000..=1999999).
    #[arg(long, default_value_t = first_heldout_seed() + 3)]
    seed: u64,
    /// The prompt to send (default: the scene's own instruction).
    #[arg(long)]
    prompt: Option<String>,
    /// The models directory the server serves.
    #[arg(long, default_value = "models")]
    models: PathBuf,
    /// Output directory (created if needed; its files are replaced): image.png, overlay.png,
    /// trajectory.json, response.json.
    #[arg(long, default_value = "demo-output")]
    out: PathBuf,
}

/// A `cnfmp serve` child process on a free loopback port, as a client runs one (the demo,
/// the end-to-end tests); dropping it stops the server (SIGTERM, then SIGKILL).
pub struct ServerProcess {
    child: Child,
    /// Receives the base URL once the server prints its "listening on" line.
    listening: mpsc::Receiver<String>,
}

impl ServerProcess {
    /// Starts `exe serve --addr 127.0.0.1:0 --models MODELS EXTRA...` and returns at once;
    /// [`ServerProcess::base_url`] waits until it listens.
    pub fn spawn(exe: &Path, models: &Path, extra: &[&str]) -> Result<ServerProcess, Failure> {
        let mut child = Command::new(exe)
            .args(["serve", "--addr", "127.0.0.1:0", "--models"])
            .arg(models)
            .args(extra)
            .stdout(Stdio::piped())
            .stdin(Stdio::null())
            .spawn()
            .map_err(|err| Failure::Environment(format!("cannot start `cnfmp serve`: {err}")))?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let (found, listening) = mpsc::channel();
        // Reads stdout to its end, so the server never writes into a closed pipe.
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(addr) = line.strip_prefix(LISTENING) {
                    let _ = found.send(format!("http://{addr}"));
                }
            }
        });
        Ok(ServerProcess { child, listening })
    }

    /// Waits (up to `timeout`) for the server to listen; returns its base URL.
    pub fn base_url(&self, timeout: Duration) -> Result<String, Failure> {
        self.listening.recv_timeout(timeout).map_err(|err| {
            Failure::Environment(match err {
                mpsc::RecvTimeoutError::Timeout => format!("the server did not listen within {} s", timeout.as_secs()),
                mpsc::RecvTimeoutError::Disconnected => "the server exited before listening (its error is above)".into(),
            })
        })
    }

    /// SIGTERM, then waits up to `grace` for a clean exit; returns whether it exited 0.
    pub fn stop(&mut self, grace: Duration) -> bool {
        // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            match self.child.try_wait() {
                Ok(Some(status)) => return status.success(),
                Ok(None) => std::thread::sleep(Duration::from_millis(50)),
                Err(_) => break,
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        false
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.stop(Duration::from_secs(10));
        }
    }
}

/// A `multipart/form-data` body of text fields and one PNG file field named "image";
/// returns (content type, body).
pub fn multipart_form(image_png: &[u8], fields: &[(&str, &str)]) -> (String, Vec<u8>) {
    let boundary = "cnfmp-form-boundary-8d1f4c";
    let mut body = Vec::new();
    for (name, value) in fields {
        body.extend_from_slice(format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n{value}\r\n").as_bytes());
    }
    body.extend_from_slice(
        format!("--{boundary}\r\nContent-Disposition: form-data; name=\"image\"; filename=\"scene.png\"\r\nContent-Type: image/png\r\n\r\n")
            .as_bytes(),
    );
    body.extend_from_slice(image_png);
    body.extend_from_slice(format!("\r\n--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// An HTTP client for the API: error statuses are answers to read (their JSON says what went
/// wrong), not transport errors; 120 s per request at most.
pub fn http_client() -> ureq::Agent {
    ureq::Agent::new_with_config(
        ureq::config::Config::builder().http_status_as_error(false).timeout_global(Some(Duration::from_secs(120))).build(),
    )
}

/// POSTs the scene to the server as a robot stack would; returns the parsed answer and the
/// client's round-trip time (s).
fn request_trajectory(base: &str, image: &[u8], prompt: &str, task: &str) -> Result<(TrajectoryResponse, String, f64), Failure> {
    let agent = http_client();
    let (content_type, body) = multipart_form(image, &[("prompt", prompt), ("task", task), ("include_masks", "true")]);
    let sent = Instant::now();
    let mut response = agent
        .post(format!("{base}/v1/trajectories"))
        .header("Content-Type", content_type)
        .send(&body[..])
        .map_err(|err| Failure::Environment(format!("the request failed: {err}")))?;
    let text = response
        .body_mut()
        .with_config()
        .limit(64 * 1024 * 1024)
        .read_to_string()
        .map_err(|err| Failure::Environment(format!("cannot read the answer: {err}")))?;
    let round_trip = sent.elapsed().as_secs_f64();
    if !response.status().is_success() {
        let message = serde_json::from_str::<ErrorResponse>(&text)
            .map(|e| format!("{} ({})", e.error.message, e.error.code))
            .unwrap_or(text);
        return Err(Failure::BadInput(format!("the server answered {}: {message}", response.status())));
    }
    let answer = serde_json::from_str(&text)
        .map_err(|err| Failure::Environment(format!("the server's answer does not match the API: {err}")))?;
    Ok((answer, text, round_trip))
}

/// The answer's trajectory, read and validated by the trajectory file reader (the answer is
/// the trajectory JSON plus diagnostics); only the prompt and model name stay as metadata.
fn trajectory_of(answer: &TrajectoryResponse, answer_text: &str) -> Result<Trajectory, Failure> {
    let mut trajectory = Trajectory::from_json_str(answer_text)
        .map_err(|err| Failure::Environment(format!("the server returned an invalid trajectory: {err}")))?;
    trajectory.metadata = Map::from_iter([
        ("prompt".to_owned(), Value::from(answer.prompt.clone())),
        ("model".to_owned(), Value::from(answer.model.name.clone())),
    ]);
    Ok(trajectory)
}

/// Requests sent after the first, to show the server's steady latency.
const WARM_REPEATS: usize = 9;

pub fn run(args: DemoArgs) -> Result<(), Failure> {
    heldout_seed_range(args.seed, 1)?;
    if !args.models.is_dir() {
        return Err(Failure::BadInput(format!("the models directory {} does not exist", args.models.display())));
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|err| Failure::BadInput(format!("cannot create {}: {err}", args.out.display())))?;
    // The server loads while this process renders the scene.
    eprintln!("starting `cnfmp serve` with the models in {} ...", args.models.display());
    let exe = std::env::current_exe()
        .map_err(|err| Failure::Environment(format!("cannot find the cnfmp binary: {err}")))?;
    let mut server = ServerProcess::spawn(&exe, &args.models, &[])?;
    let bridge = Bridge::start_default()?;
    let simulator = Simulator::new(bridge)?;
    let scene = simulator.render(&args.task, args.seed, false)?;
    let prompt = args.prompt.clone().unwrap_or_else(|| scene.info.prompt.clone());
    eprintln!("rendered held-out {} scene {} ({}); waiting for the server ...", args.task, args.seed, scene.info.objects.join(", "));
    let base = server.base_url(SERVER_START_TIMEOUT)?;

    eprintln!("POST {base}/v1/trajectories  prompt={prompt:?}");
    let (answer, answer_text, round_trip_s) = request_trajectory(&base, &scene.image, &prompt, &args.task)?;
    let trajectory = trajectory_of(&answer, &answer_text)?;
    // The first request is the server's first; a few more show that it was already warm.
    let mut repeats = (0..WARM_REPEATS)
        .map(|_| request_trajectory(&base, &scene.image, &prompt, &args.task).map(|(_, _, seconds)| seconds))
        .collect::<Result<Vec<f64>, Failure>>()?;
    repeats.sort_by(f64::total_cmp);
    let warm_p50_s = repeats[repeats.len() / 2];
    let verdict = simulator.execute(&args.task, args.seed, &simulator.at_control_rate(&trajectory)?)?;

    let masks = answer
        .masks_png_base64
        .as_deref()
        .map(|text| base64::engine::general_purpose::STANDARD.decode(text))
        .transpose()
        .map_err(|err| Failure::Environment(format!("the server's masks are not base64: {err}")))?;
    let arrays = trajectory.to_arrays();
    let overlay = bridge.sim_draw_trajectory(scene.image.clone(), masks, arrays.position, arrays.gripper)?;
    let outputs = [
        ("image.png", scene.image),
        ("overlay.png", overlay),
        ("trajectory.json", trajectory.to_json_string().into_bytes()),
        ("response.json", answer_text.into_bytes()),
    ];
    for (name, contents) in &outputs {
        write_atomically(&args.out.join(name), contents)?;
    }
    let stopped_cleanly = server.stop(Duration::from_secs(30));
    let mut report = answer_report(&args, &prompt, &answer, round_trip_s, &trajectory);
    report.push(format!(
        "warm       the next {WARM_REPEATS} requests: round trip p50 {:.1} ms (the first: {:.1} ms)",
        warm_p50_s * 1e3,
        round_trip_s * 1e3
    ));
    report.push(format!(
        "simulator  {}",
        if verdict.success { "SUCCESS: the task was completed".to_owned() } else { format!("FAILED: {}", verdict.reasons.join("; ")) }
    ));
    report.push(format!("server     stopped by SIGTERM, {}", if stopped_cleanly { "exit 0" } else { "did NOT exit cleanly" }));
    report.push(format!(
        "wrote      {}",
        outputs.iter().map(|(name, _)| args.out.join(name).display().to_string()).collect::<Vec<_>>().join(", ")
    ));
    print_stdout(&report.join("\n"))?;
    if !stopped_cleanly {
        return Err(Failure::Environment("the server did not shut down cleanly on SIGTERM".into()));
    }
    Ok(())
}

/// The report's lines on the scene, the objects the server found and its timings.
fn answer_report(args: &DemoArgs, prompt: &str, answer: &TrajectoryResponse, round_trip_s: f64, trajectory: &Trajectory) -> Vec<String> {
    let t = &answer.timings_ms;
    let mut report = vec![
        format!("scene      {} seed {} (held-out), prompt {prompt:?}", args.task, args.seed),
        format!(
            "model      {} ({} objects found {})",
            answer.model.name,
            answer.objects.iter().filter(|o| o.found).count(),
            answer.segmenter.as_ref().map_or("in the given masks".into(), |backend| format!("by the {backend} segmenter"))
        ),
    ];
    for object in &answer.objects {
        let fit = object.confidence.as_ref().and_then(|c| c.psnr_db).map(|p| format!(", fit {p:.1} dB")).unwrap_or_default();
        let slot = object.slot.map(|s| format!("slot {s}")).unwrap_or_else(|| "unused".into());
        let box_text = object.bbox.map(|b| format!("box {b:?}")).unwrap_or_else(|| "not found".into());
        report.push(format!("  {:<12} {:<14} score {:.2}, {box_text}, {slot}{fit}", object.role, object.phrase, object.score));
    }
    report.push(format!(
        "timings    queue {:.1} ms, segment {:.1} ms, infer {:.1} ms, server total {:.1} ms, client round trip {:.1} ms",
        t.queue_ms, t.segment_ms, t.infer_ms, t.total_ms, round_trip_s * 1e3
    ));
    report.push(format!("trajectory {} frames at {} Hz ({:.1} s)", trajectory.frames.len(), trajectory.fps, trajectory.duration()));
    report
}
