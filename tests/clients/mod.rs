//! Independent clients of the control-room services, set up by the tests
//! themselves: the Foxglove WebSocket client in Node (scripts/nodeenv.sh), the
//! Zenoh subscriber in Python (scripts/pyenv.sh); the viewer and the bridge as
//! processes; two network namespaces joined by a veth pair; and the check that
//! what a client decoded is what the run recorded.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

// Each test binary uses a subset of these helpers.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, RosType, Sample};
use jetbench_record::Recording;
use serde_json::Value;

use crate::common::{lines_of, repo_root, wait_with_watchdog};

/// A TCP port nobody listens on now (the OS picks it; a test binds it right after).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("bind a free port").port()
}

/// The bus namespace of `common::jetbench(suite)`.
pub fn namespace(suite: &str) -> String {
    format!("{suite}{}", std::process::id())
}

/// A started process with its output read line by line.
pub struct Process {
    pub child: Child,
    pub stdout: mpsc::Receiver<String>,
    pub stderr: mpsc::Receiver<String>,
    what: String,
}

impl Process {
    /// Starts `command` and waits (at most 60 s) for a line containing `ready_line` on its stdout.
    pub fn start(mut command: Command, ready_line: &str, what: &str) -> Process {
        let mut child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {what}: {e}"));
        let stdout = lines_of(child.stdout.take().expect("stdout"));
        let stderr = lines_of(child.stderr.take().expect("stderr"));
        let mut process = Process { child, stdout, stderr, what: what.into() };
        loop {
            match process.stdout.recv_timeout(Duration::from_secs(60)) {
                Ok(line) if line.contains(ready_line) => return process,
                Ok(_) => {}
                Err(_) => {
                    let _ = process.child.kill();
                    let _ = process.child.wait();
                    panic!("{what} did not print {ready_line:?}:\n{}", process.stderr_text());
                }
            }
        }
    }

    /// SIGTERM, then waits (watchdog 30 s); returns whether it exited 0 and its stderr.
    pub fn stop(mut self) -> (bool, String) {
        // SAFETY: signalling a child this test started and has not reaped.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let status = wait_with_watchdog(&mut self.child, Duration::from_secs(30), &self.what);
        (status.success(), self.stderr_text())
    }

    /// Waits for it to end by itself (watchdog `limit`); whether it exited 0, and its output.
    pub fn wait(mut self, limit: Duration) -> (bool, String) {
        let status = wait_with_watchdog(&mut self.child, limit, &self.what);
        let out: Vec<String> = self.stdout.try_iter().collect();
        (status.success(), format!("{}\n{}", out.join("\n"), self.stderr_text()))
    }

    /// Kills it at once (a client that never reads would never notice a close).
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    fn stderr_text(&self) -> String {
        let mut lines = Vec::new();
        while let Ok(line) = self.stderr.recv_timeout(Duration::from_millis(500)) {
            lines.push(line);
        }
        lines.join("\n")
    }
}

/// `command` run inside network namespace `netns`, if one is given.
pub fn in_netns(netns: Option<&str>, program: &Path) -> Command {
    match netns {
        Some(ns) => {
            let mut command = Command::new("ip");
            command.args(["netns", "exec", ns]).arg(program);
            command
        }
        None => Command::new(program),
    }
}

/// The folder of the installed Node client (scripts/nodeenv.sh).
pub fn node_env() -> PathBuf {
    let out = Command::new(repo_root().join("scripts/nodeenv.sh")).output().expect("run scripts/nodeenv.sh");
    assert!(out.status.success(), "scripts/nodeenv.sh failed:\n{}", String::from_utf8_lossy(&out.stderr));
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// Starts the Node Foxglove client on `url` (see tests/clients/foxglove_client.mjs).
pub fn foxglove_client(env: &Path, url: &str, topics: &[&str], extra: &[&str]) -> Process {
    let mut command = Command::new("node");
    command.arg(env.join("foxglove_client.mjs")).arg(url).arg("--topics").arg(topics.join(",")).args(extra);
    Process::start(command, "subscribed", "the Node Foxglove client")
}

/// Two network namespaces joined by a veth pair, as two hosts on a link:
/// the bench at `10.199.X.1`, the control room at `10.199.X.2`. Removed on drop.
pub struct TwoHosts {
    pub bench: String,
    pub control_room: String,
    pub bench_ip: String,
    /// The bench's end of the veth pair.
    bench_link: String,
}

impl TwoHosts {
    /// `Err` with the reason when this machine cannot make them (not root, no `ip`).
    pub fn create() -> Result<TwoHosts, String> {
        // Unique per test of this process too: tests run side by side.
        static MADE: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = MADE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let id = format!("{}x{n}", std::process::id());
        let subnet = (std::process::id() + n) % 250;
        let (a, b) = (format!("jbv{id}a"), format!("jbv{id}b"));
        let hosts = TwoHosts {
            bench: format!("jbbench{id}"),
            control_room: format!("jbctl{id}"),
            bench_ip: format!("10.199.{subnet}.1"),
            bench_link: a.clone(),
        };
        let peer_ip = format!("10.199.{subnet}.2");
        let steps: Vec<Vec<&str>> = vec![
            vec!["netns", "add", &hosts.bench],
            vec!["netns", "add", &hosts.control_room],
            vec!["link", "add", &a, "type", "veth", "peer", "name", &b],
            vec!["link", "set", &a, "netns", &hosts.bench],
            vec!["link", "set", &b, "netns", &hosts.control_room],
        ];
        let bench_addr = format!("{}/30", hosts.bench_ip);
        let peer_addr = format!("{peer_ip}/30");
        let inside: Vec<(&str, Vec<&str>)> = vec![
            (&hosts.bench, vec!["addr", "add", &bench_addr, "dev", &a]),
            (&hosts.bench, vec!["link", "set", &a, "up"]),
            (&hosts.bench, vec!["link", "set", "lo", "up"]),
            (&hosts.control_room, vec!["addr", "add", &peer_addr, "dev", &b]),
            (&hosts.control_room, vec!["link", "set", &b, "up"]),
            (&hosts.control_room, vec!["link", "set", "lo", "up"]),
        ];
        let run = |args: &[&str]| -> Result<(), String> {
            let out = Command::new("ip").args(args).output().map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
            if out.status.success() {
                Ok(())
            } else {
                Err(format!("ip {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
            }
        };
        for args in &steps {
            run(args)?;
        }
        for (ns, args) in &inside {
            let mut full = vec!["-n", ns];
            full.extend(args);
            run(&full)?;
        }
        Ok(hosts)
    }
}

impl TwoHosts {
    /// Takes the bench's end of the link down, as a pulled network cable does.
    #[allow(dead_code)]
    pub fn pull_cable(&self) -> Result<(), String> {
        self.bench_link("down")
    }

    /// Brings it up again.
    #[allow(dead_code)]
    pub fn plug_cable(&self) -> Result<(), String> {
        self.bench_link("up")
    }

    fn bench_link(&self, state: &str) -> Result<(), String> {
        let veth = &self.bench_link;
        let out = Command::new("ip")
            .args(["-n", &self.bench, "link", "set", veth, state])
            .output()
            .map_err(|e| format!("ip link set {veth} {state}: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!("ip link set {veth} {state}: {}", String::from_utf8_lossy(&out.stderr).trim()))
        }
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        // Deleting a namespace deletes the veth end inside it, and with it the pair.
        for ns in [&self.bench, &self.control_room] {
            let _ = Command::new("ip").args(["netns", "del", ns]).output();
        }
    }
}

/// The stream a sample belongs to: its service for `bench/health`, else one.
fn stream_of<T: Sample>(sample: &T) -> u32 {
    T::FIELDS
        .iter()
        .find(|f| f.name == "service_id")
        .map_or(0, |f| u32::from_le_bytes(sample.as_bytes()[f.offset..f.offset + 4].try_into().unwrap()))
}

/// A decoded value equals the little-endian value at the start of `bytes`:
/// floats bit for bit (NaN as NaN), integers exactly (as numbers or, from
/// JavaScript's bigints, strings).
fn value_matches(ty: RosType, bytes: &[u8], value: &Value) -> bool {
    let p = ty.primitive();
    match ty {
        RosType::Array(_, n) => value.as_array().is_some_and(|items| {
            items.len() == n
                && items.iter().enumerate().all(|(i, v)| value_matches(RosType::Scalar(p), &bytes[i * p.size()..], v))
        }),
        RosType::Scalar(_) => {
            let text = ty.format_value(bytes);
            match p.name() {
                "float64" | "float32" => {
                    let ours: f64 = text.parse().unwrap();
                    value.as_f64().is_some_and(|v| v == ours || (v.is_nan() && ours.is_nan()))
                        || value.as_str().is_some_and(|s| s.parse::<f64>().is_ok_and(|v| v.is_nan() && ours.is_nan()))
                }
                _ => value.as_u64().map(|v| v.to_string()).or_else(|| value.as_str().map(String::from)) == Some(text),
            }
        }
    }
}

/// What a client decoded of one channel, against the recording: the samples
/// that matched, how many the recording has from each publisher's first to last
/// sample the client saw (what was published while it was connected), and the
/// first few differences.
pub fn compare_with_recording<T: Sample>(
    recording: &Recording,
    channel: jetbench_msgs::Channel<T>,
    decoded: &[Value],
) -> (usize, usize, Vec<String>) {
    let recorded: HashMap<(u32, u64), T> =
        recording.samples(channel).into_iter().map(|s| ((stream_of(&s), s.seq()), s)).collect();
    // Each publisher's first and last recorded seq: a sample from before the
    // recorder started or after it stopped (a bridge outliving the run) is not
    // expected in the recording.
    let mut recorded_span: HashMap<u32, (u64, u64)> = HashMap::new();
    for &(stream, seq) in recorded.keys() {
        widen(&mut recorded_span, stream, seq);
    }
    let mut seen_span: HashMap<u32, (u64, u64)> = HashMap::new();
    let mut matched = 0;
    let mut failures = Vec::new();
    for message in decoded {
        let seq = message["seq"].as_u64().or_else(|| message["seq"].as_str().and_then(|s| s.parse().ok()));
        let stream = message["service_id"].as_u64().unwrap_or(0) as u32;
        let outside = |seq: u64| recorded_span.get(&stream).is_some_and(|&(first, last)| seq < first || seq > last);
        if seq.is_some_and(outside) {
            continue;
        }
        let Some(sample) = seq.and_then(|seq| recorded.get(&(stream, seq))) else {
            failures.push(format!("{}: {message} is not in the recording", channel.name));
            continue;
        };
        widen(&mut seen_span, stream, sample.seq());
        let bytes = sample.as_bytes();
        let wrong: Vec<&str> = T::FIELDS
            .iter()
            .filter(|f| !value_matches(f.ros_type, &bytes[f.offset..], &message[f.name]))
            .map(|f| f.name)
            .collect();
        if wrong.is_empty() {
            matched += 1;
        } else {
            failures.push(format!("{}: fields {wrong:?} differ: decoded {message}, recorded {sample:?}", channel.name));
        }
    }
    let published = recorded
        .keys()
        .filter(|(stream, seq)| seen_span.get(stream).is_some_and(|&(first, last)| (first..=last).contains(seq)))
        .count();
    failures.truncate(5);
    (matched, published, failures)
}

fn widen(spans: &mut HashMap<u32, (u64, u64)>, stream: u32, seq: u64) {
    let span = spans.entry(stream).or_insert((seq, seq));
    *span = (span.0.min(seq), span.1.max(seq));
}

/// Every channel: at least 95 % of the samples published while the subscriber
/// was connected decoded, each equal to the recording.
struct CompareAll<'a> {
    recording: &'a Recording,
    got: &'a Value,
    failures: Vec<String>,
}

impl ChannelVisitor for CompareAll<'_> {
    fn visit<T: Sample>(&mut self, channel: Channel<T>) {
        let decoded = self.got["messages"][channel.topic()].as_array().cloned().unwrap_or_default();
        let (matched, published, failures) = compare_with_recording(self.recording, channel, &decoded);
        let recorded = self.recording.samples(channel).len();
        self.failures.extend(failures);
        eprintln!(
            "{:<18} {matched:>6} of {published:>6} samples published while connected received and equal",
            channel.topic()
        );
        // A sparse channel (bench/events: a few samples, some before the client could
        // subscribe) is judged by what was published while connected only.
        let streamed = recorded >= 100;
        if (matched as f64) < 0.95 * published as f64 || (streamed && published * 2 < recorded) {
            self.failures.push(format!(
                "{}: {matched} of the {published} samples published while connected arrived ({recorded} recorded)",
                channel.name
            ));
        }
        let encoding = format!("application/cdr;{}", T::schema_name());
        if (streamed || !decoded.is_empty()) && self.got["encodings"][channel.topic()] != encoding.as_str() {
            self.failures.push(format!("{}: encoding {}", channel.name, self.got["encodings"][channel.topic()]));
        }
    }
}

/// What the Zenoh subscriber decoded (its JSON), against the recording, every
/// channel: the failures, none when every channel holds.
pub fn compare_every_channel(recording: &Recording, got: &Value) -> Vec<String> {
    let mut compare = CompareAll { recording, got, failures: Vec::new() };
    visit_channels(&mut compare);
    compare.failures
}

/// The Python Zenoh subscriber (tests/clients/zenoh_subscriber.py), in network
/// namespace `netns` (this host's with `None`), connected to `endpoint` for
/// suite `suite`'s bus namespace; it writes what it decoded to `out`, judged
/// against `recording` once the run is over. Started and subscribed.
pub fn zenoh_subscriber(netns: Option<&str>, endpoint: &str, suite: &str, out: &Path, recording: &Path) -> Process {
    let mut command = in_netns(netns, &crate::common::python());
    command
        .arg(repo_root().join("tests/clients/zenoh_subscriber.py"))
        .args(["--connect", endpoint, "--namespace", &namespace(suite), "--out"])
        .arg(out)
        .arg("--recording")
        .arg(recording);
    Process::start(command, "subscribed", "the Python Zenoh subscriber")
}

/// Certificates made by the test with the `openssl` command: a CA the bench trusts,
/// the bench's certificate (valid for `bench_ip`), a client certificate per trusted
/// name, and an untrusted client from another CA that claims a trusted name.
pub struct TestPki {
    pub dir: PathBuf,
}

impl TestPki {
    /// Makes `ca.crt`, `bench.{crt,key}`, `<name>.{crt,key}` for each of `clients` (signed by
    /// the CA) and `untrusted.{crt,key}` (CN `untrusted_cn`, signed by `rogue-ca.crt`) in `dir`.
    pub fn make(dir: &Path, bench_ip: &str, clients: &[&str], untrusted_cn: &str) -> TestPki {
        let openssl = jetbench_latency::pki::Openssl::in_dir(dir).unwrap();
        let done = |step: Result<(), String>| step.unwrap_or_else(|e| panic!("{e}"));
        done(openssl.ca("ca", "jetbench test ca"));
        done(openssl.ca("rogue-ca", "jetbench test rogue-ca"));
        done(openssl.leaf("bench", "bench", "ca", &format!("IP:{bench_ip},IP:127.0.0.1,DNS:localhost")));
        for name in clients {
            done(openssl.leaf(name, name, "ca", &format!("DNS:{name}")));
        }
        done(openssl.leaf("untrusted", untrusted_cn, "rogue-ca", &format!("DNS:{untrusted_cn}")));
        TestPki { dir: dir.to_path_buf() }
    }

    pub fn path(&self, file: &str) -> String {
        self.dir.join(file).display().to_string()
    }
}

/// Runs tests/clients/zenoh_command.py in `netns`: connects to `endpoint` (with the
/// client certificate `client` of `pki`, if any), queries each of `queries`
/// (`KEY[=VALUE]`) in turn; returns each query's replies, or `Err` with the connect
/// error.
pub fn zenoh_commands(
    netns: Option<&str>,
    endpoint: &str,
    tls: Option<(&TestPki, &str)>,
    queries: &[String],
) -> Result<Vec<(String, Vec<String>)>, String> {
    let mut command = in_netns(netns, &crate::common::python());
    command.arg(repo_root().join("tests/clients/zenoh_command.py")).args(["--connect", endpoint]);
    if let Some((pki, client)) = tls {
        command.args(["--ca", &pki.path("ca.crt"), "--cert", &pki.path(&format!("{client}.crt"))]);
        command.args(["--key", &pki.path(&format!("{client}.key"))]);
    }
    command.args(queries);
    let out = command.output().expect("run zenoh_command.py");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let mut answers = Vec::new();
    for line in stdout.lines().filter(|l| l.starts_with('{')) {
        let v: Value = serde_json::from_str(line).unwrap();
        if let Some(e) = v["connect_error"].as_str() {
            return Err(e.to_string());
        }
        if let Some(s) = v["slept"].as_f64() {
            answers.push((format!("sleep={s}"), Vec::new()));
            continue;
        }
        let replies = v["replies"].as_array().unwrap().iter().map(|r| r.as_str().unwrap().to_string()).collect();
        answers.push((v["key"].as_str().unwrap().to_string(), replies));
    }
    assert!(
        out.status.success() && answers.len() == queries.len(),
        "zenoh_command.py failed ({}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(answers)
}
