//! Prometheus metrics in the text exposition format (`GET /metrics`): request counts by
//! route and status, error counts by code, latency histograms per route and per pipeline
//! stage, and the queue's state. Small enough to keep by hand under one mutex.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;

/// Histogram bucket upper bounds (s): from a cached segmentation to a slow CPU request.
const BUCKETS_S: [f64; 14] = [0.005, 0.01, 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0];

#[derive(Debug, Clone, Default)]
struct Histogram {
    /// Non-cumulative counts per bucket; the last slot is +Inf.
    counts: [u64; BUCKETS_S.len() + 1],
    sum: f64,
}

impl Histogram {
    fn observe(&mut self, seconds: f64) {
        let bucket = BUCKETS_S.iter().position(|&bound| seconds <= bound).unwrap_or(BUCKETS_S.len());
        self.counts[bucket] += 1;
        self.sum += seconds;
    }

    fn render(&self, out: &mut String, name: &str, label: &str) {
        let mut cumulative = 0;
        for (bound, count) in BUCKETS_S.iter().zip(self.counts) {
            cumulative += count;
            let _ = writeln!(out, "{name}_bucket{{{label},le=\"{bound}\"}} {cumulative}");
        }
        cumulative += self.counts[BUCKETS_S.len()];
        let _ = writeln!(out, "{name}_bucket{{{label},le=\"+Inf\"}} {cumulative}");
        let _ = writeln!(out, "{name}_sum{{{label}}} {}", self.sum);
        let _ = writeln!(out, "{name}_count{{{label}}} {cumulative}");
    }
}

#[derive(Debug, Default)]
struct Inner {
    requests: BTreeMap<(String, u16), u64>,
    errors: BTreeMap<(String, &'static str), u64>,
    request_seconds: BTreeMap<String, Histogram>,
    stage_seconds: BTreeMap<&'static str, Histogram>,
}

/// Every metric the server exports.
#[derive(Debug, Default)]
pub struct Metrics {
    inner: Mutex<Inner>,
}

/// The queue's state at scrape time.
pub struct QueueGauges {
    pub depth: usize,
    pub capacity: usize,
    pub pending: usize,
}

impl Metrics {
    /// Records a finished request: its route (the matched path pattern), status, error code
    /// (for error answers) and duration (s).
    pub fn record_request(&self, route: &str, status: u16, error_code: Option<&'static str>, seconds: f64) {
        let mut inner = self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        *inner.requests.entry((route.to_owned(), status)).or_default() += 1;
        if let Some(code) = error_code {
            *inner.errors.entry((route.to_owned(), code)).or_default() += 1;
        }
        inner.request_seconds.entry(route.to_owned()).or_default().observe(seconds);
    }

    /// Records one pipeline stage's duration (s): queue, segment, infer, total.
    pub fn record_stage(&self, stage: &'static str, seconds: f64) {
        let mut inner = self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        inner.stage_seconds.entry(stage).or_default().observe(seconds);
    }

    /// The text exposition format (version 0.0.4).
    pub fn render(&self, queue: QueueGauges) -> String {
        let inner = self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let mut out = String::new();
        out.push_str("# HELP cnfmp_http_requests_total HTTP requests answered, by route and status.\n");
        out.push_str("# TYPE cnfmp_http_requests_total counter\n");
        for ((route, status), count) in &inner.requests {
            let _ = writeln!(out, "cnfmp_http_requests_total{{route=\"{route}\",status=\"{status}\"}} {count}");
        }
        out.push_str("# HELP cnfmp_http_errors_total Error answers, by route and error code.\n");
        out.push_str("# TYPE cnfmp_http_errors_total counter\n");
        for ((route, code), count) in &inner.errors {
            let _ = writeln!(out, "cnfmp_http_errors_total{{route=\"{route}\",code=\"{code}\"}} {count}");
        }
        out.push_str("# HELP cnfmp_http_request_duration_seconds Time to answer a request, by route.\n");
        out.push_str("# TYPE cnfmp_http_request_duration_seconds histogram\n");
        for (route, histogram) in &inner.request_seconds {
            histogram.render(&mut out, "cnfmp_http_request_duration_seconds", &format!("route=\"{route}\""));
        }
        out.push_str("# HELP cnfmp_stage_duration_seconds Time per stage of a trajectory request (queue, segment, infer, total).\n");
        out.push_str("# TYPE cnfmp_stage_duration_seconds histogram\n");
        for (stage, histogram) in &inner.stage_seconds {
            histogram.render(&mut out, "cnfmp_stage_duration_seconds", &format!("stage=\"{stage}\""));
        }
        out.push_str("# HELP cnfmp_queue_depth Requests waiting for the Python worker.\n");
        out.push_str("# TYPE cnfmp_queue_depth gauge\n");
        let _ = writeln!(out, "cnfmp_queue_depth {}", queue.depth);
        out.push_str("# HELP cnfmp_queue_capacity Requests that may wait before the server answers 503.\n");
        out.push_str("# TYPE cnfmp_queue_capacity gauge\n");
        let _ = writeln!(out, "cnfmp_queue_capacity {}", queue.capacity);
        out.push_str("# HELP cnfmp_queue_pending Requests waiting or running in the Python worker.\n");
        out.push_str("# TYPE cnfmp_queue_pending gauge\n");
        let _ = writeln!(out, "cnfmp_queue_pending {}", queue.pending);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histograms_are_cumulative_and_counted() {
        let metrics = Metrics::default();
        metrics.record_stage("segment", 0.012);
        metrics.record_stage("segment", 0.2);
        metrics.record_stage("segment", 99.0);
        metrics.record_request("/v1/trajectories", 503, Some("overloaded"), 0.001);
        let text = metrics.render(QueueGauges { depth: 2, capacity: 8, pending: 3 });
        assert!(text.contains("cnfmp_stage_duration_seconds_bucket{stage=\"segment\",le=\"0.01\"} 0\n"), "{text}");
        assert!(text.contains("cnfmp_stage_duration_seconds_bucket{stage=\"segment\",le=\"0.025\"} 1\n"), "{text}");
        assert!(text.contains("cnfmp_stage_duration_seconds_bucket{stage=\"segment\",le=\"0.2\"} 2\n"), "{text}");
        assert!(text.contains("cnfmp_stage_duration_seconds_bucket{stage=\"segment\",le=\"+Inf\"} 3\n"), "{text}");
        assert!(text.contains("cnfmp_stage_duration_seconds_count{stage=\"segment\"} 3\n"), "{text}");
        assert!(text.contains("cnfmp_http_requests_total{route=\"/v1/trajectories\",status=\"503\"} 1\n"), "{text}");
        assert!(text.contains("cnfmp_http_errors_total{route=\"/v1/trajectories\",code=\"overloaded\"} 1\n"), "{text}");
        assert!(text.contains("cnfmp_queue_depth 2\n"), "{text}");
    }
}
