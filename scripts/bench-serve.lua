-- wrk script of scripts/bench-serve.sh: POSTs the JSON request in $BENCH_BODY to
-- /v1/trajectories and counts answers by status (200 served, 503 refused by the full queue,
-- anything else an error). Like a well-behaved client, a connection refused with 503 waits
-- the Retry-After seconds before its next request (wrk's delay() hook; the wait is not part
-- of any latency). Counters live per wrk thread; done() adds them up.
local threads = {}

function setup(thread)
    table.insert(threads, thread)
end

function init(args)
    local file = assert(io.open(os.getenv("BENCH_BODY"), "rb"))
    wrk.method = "POST"
    wrk.body = file:read("*a")
    wrk.headers["Content-Type"] = "application/json"
    file:close()
    served, refused, other = 0, 0, 0
    backoff_ms = 0
end

function delay()
    local wait = backoff_ms
    backoff_ms = 0
    return wait
end

function response(status, headers, body)
    if status == 200 then
        served = served + 1
    elseif status == 503 then
        refused = refused + 1
        backoff_ms = 1000 * (tonumber(headers["retry-after"] or headers["Retry-After"]) or 1)
    else
        other = other + 1
    end
end

function done(summary, latency, requests)
    local s, r, o = 0, 0, 0
    for _, thread in ipairs(threads) do
        s, r, o = s + thread:get("served"), r + thread:get("refused"), o + thread:get("other")
    end
    local e = summary.errors
    local seconds = summary.duration / 1e6
    io.write(string.format(
        "RESULT requests=%d rps=%.2f served=%d served_rps=%.2f refused_503=%d other_status=%d socket_errors=%d p50_ms=%.1f p99_ms=%.1f\n",
        summary.requests, summary.requests / seconds, s, s / seconds, r, o,
        e.connect + e.read + e.write + e.timeout, latency:percentile(50) / 1e3, latency:percentile(99) / 1e3))
end
