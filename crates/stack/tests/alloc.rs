//! The per-cycle work of every service allocates nothing after start-up.
//!
//! A counting global allocator (`allocation-counter`) counts the allocations
//! made on the test's own thread while the services' step code runs cycle
//! after cycle (after a warm-up that lets buffers reach their working size):
//! the step structs of the simulated bench, sensing, estimation, every control
//! law and actuation, the CAN codec between sim-bench and sensing, and the
//! throttle board's frame codec. A heap allocation in a 100 Hz loop is a system call waiting to
//! happen at the worst moment; this test keeps them out of our code.
//!
//! Two libraries allocate inside calls we cannot avoid, and the test pins them
//! to exactly that: iceoryx2 0.10, one small reference-counted state per loaned
//! sample (so one per publish), and Clarabel 0.11, one per QP solve (the MPC's
//! Gauss-Newton passes). Both come from the allocator's thread cache, not the
//! kernel, once the process runs.

use std::time::Duration;

use jetbench_bus::{Bus, Publisher, Subscriber};
use jetbench_control::{Controller, Profile};
use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface};
use jetbench_io::emulate::PtyBoard;
use jetbench_io::serial::ThrottleBoard;
use jetbench_io::{ForceSink, ForceSource, ThrottleOutput};
use jetbench_msgs::{Actuation, Channel, Command, StateEstimate, Thrust};
use jetbench_stack::actuation::ActuationStep;
use jetbench_stack::config::BenchConfig;
use jetbench_stack::control::ControlStep;
use jetbench_stack::estimation::EstimationStep;
use jetbench_stack::sensing::SensingStep;
use jetbench_stack::sim_bench::{SimBenchStep, SimForceSensor};

/// Allocations made on this thread by `f`.
fn allocations(f: impl FnOnce()) -> u64 {
    allocation_counter::measure(f).count_total
}

/// The whole loop in one thread, as the services run it, through the real
/// transports: sim-bench → CAN frames over the userspace CAN bus → sensing →
/// bus → estimation → bus → control → bus → actuation → the throttle board
/// driver over a pty to the emulated board (whose own thread is not counted:
/// it is a device, not a service).
struct Loop {
    sim: SimBenchStep,
    sensor: CanForceSink,
    source: CanForceSource,
    sensing: SensingStep,
    estimation: EstimationStep,
    control: ControlStep,
    actuator: ActuationStep,
    board: ThrottleBoard,
    _emulator: PtyBoard,
    bus: Buses,
    k: u64,
    /// Allocations per stage, in [`STAGES`] order.
    counts: [u64; 9],
}

const STAGES: [&str; 9] = [
    "sim-bench engine step",
    "CAN send",
    "CAN receive and pairing",
    "sensing step",
    "bus hand-over",
    "estimation step",
    "control step",
    "actuation step",
    "throttle board write and ack",
];

struct Buses {
    _bus: Bus,
    thrust: (Publisher<Thrust>, Subscriber<Thrust>),
    state: (Publisher<StateEstimate>, Subscriber<StateEstimate>),
    command: (Publisher<Command>, Subscriber<Command>),
    actuation: (Publisher<Actuation>, Subscriber<Actuation>),
}

/// Publishes `sample` and takes it back off the bus, as the next service would.
fn hand_over<T: jetbench_msgs::Sample>(ports: &mut (Publisher<T>, Subscriber<T>), sample: T) -> T {
    ports.0.publish(sample).expect("publish");
    ports.1.latest().expect("receive").expect("the sample just published")
}

fn clock() -> u64 {
    jetbench_stack::runtime::clock::monotonic_ns()
}

impl Loop {
    fn new(kind: Controller) -> Loop {
        static NAMESPACE: std::sync::Once = std::sync::Once::new();
        NAMESPACE.call_once(|| {
            // SAFETY: set once, before any thread of this test binary reads it.
            unsafe { std::env::set_var(jetbench_bus::NAMESPACE_ENV, format!("alloc{}", std::process::id())) };
        });
        let mut config = BenchConfig::default_sim().expect("built-in config");
        config.control.controller = kind;
        let (params, observer) = config.estimator().expect("model");
        let idle = params.stable_equilibrium(25.0).expect("idle");
        let max = params.stable_equilibrium(100.0).expect("max");
        // The steps profile saturates the throttle both ways, so every branch of
        // the laws (and the MPC's active constraints) runs during the count.
        let profile = Profile::builtin("steps", idle, max).expect("profile");
        let codec = config.sensor.codec().expect("codec");
        let can = CanInterface::userspace(
            &format!("alloc{}{kind}", std::process::id()),
            &format!("alloc{}", std::process::id()),
        );
        let source = CanForceSource::open(&can, codec).expect("CAN listener");
        let sensor = CanForceSink::open(&can, codec).expect("CAN sender");
        let link = std::env::temp_dir().join(format!("jetbench-alloc-{}-{kind}", std::process::id()));
        let emulator = PtyBoard::spawn(&link, clock).expect("emulated board");
        let bus = Bus::open(&format!("alloc-{kind}")).expect("bus");
        let k = kind_index(kind);
        let buses = Buses {
            thrust: ports(&bus, THRUST[k]),
            state: ports(&bus, STATE[k]),
            command: ports(&bus, COMMAND[k]),
            actuation: ports(&bus, ACTUATION[k]),
            _bus: bus,
        };
        Loop {
            sim: SimBenchStep::new(
                &config.plant().expect("plant"),
                SimForceSensor::new(config.plant.noise_var_n2, config.plant.sensor_zero, 5).expect("sensor"),
                25.0,
            ),
            sensor,
            source,
            sensing: SensingStep::new(&config.sensor).expect("sensing"),
            estimation: EstimationStep::new(params, observer),
            control: ControlStep::with_law(config.control_law().expect("law"), profile),
            actuator: ActuationStep::new(3),
            board: ThrottleBoard::new(&link, 115_200, clock),
            _emulator: emulator,
            bus: buses,
            k: 0,
            counts: [0; 9],
        }
    }

    fn cycle(&mut self) {
        let now_ns = clock();
        self.k += 1;
        let throttle = self.actuator_output();
        let (reading, _truth) = self.stage(0, |l| l.sim.step_driven(now_ns, throttle).expect("sim step"));
        self.stage(1, |l| l.sensor.emit(&reading, now_ns).expect("send CAN frames"));
        let reading =
            self.stage(2, |l| l.source.read(Duration::from_millis(100)).expect("CAN").expect("a force/torque pair"));
        let thrust = self.stage(3, |l| l.sensing.step(&reading, clock()).expect("sensing"));
        let thrust = self.stage(4, |l| hand_over(&mut l.bus.thrust, thrust));
        let state = self.stage(5, |l| l.estimation.step(&thrust).expect("estimation"));
        let state = self.stage(4, |l| hand_over(&mut l.bus.state, state));
        let (_reference, command) = self.stage(6, |l| l.control.step(&state).expect("control"));
        let command = self.stage(4, |l| hand_over(&mut l.bus.command, command));
        let output = self.stage(7, |l| l.actuator.on_command(&command));
        self.stage(8, |l| l.board.write(output.applied_pct).expect("board write"));
        let output = self.stage(7, |l| {
            l.actuator.with_board(output, l.board.acknowledged(), l.board.unacked_writes(), l.board.silent_writes())
        });
        let applied = self.stage(4, |l| hand_over(&mut l.bus.actuation, output));
        self.estimation.set_applied(applied.applied_pct);
    }

    /// Runs one stage of the cycle, adding its allocations to its count.
    fn stage<R>(&mut self, index: usize, f: impl FnOnce(&mut Self) -> R) -> R {
        let mut r = None;
        self.counts[index] += allocations(|| r = Some(f(self)));
        r.expect("the stage ran")
    }

    fn actuator_output(&self) -> f64 {
        self.board.acknowledged().map_or(25.0, |a| a.applied_pct)
    }
}

/// A publisher and a subscriber of `channel`: one hand-over of the loop.
fn ports<T: jetbench_msgs::Sample>(bus: &Bus, channel: Channel<T>) -> (Publisher<T>, Subscriber<T>) {
    (bus.publisher(channel).expect("pub"), bus.subscriber(channel, 4).expect("sub"))
}

fn kind_index(kind: Controller) -> usize {
    match kind {
        Controller::Fbl => 0,
        Controller::Smc => 1,
        _ => 2,
    }
}

// Channels private to each test (they run in parallel in one process).
const THRUST: [Channel<Thrust>; 3] =
    [Channel::new("alloc/fbl/thrust"), Channel::new("alloc/smc/thrust"), Channel::new("alloc/mpc/thrust")];
const STATE: [Channel<StateEstimate>; 3] =
    [Channel::new("alloc/fbl/state"), Channel::new("alloc/smc/state"), Channel::new("alloc/mpc/state")];
const COMMAND: [Channel<Command>; 3] =
    [Channel::new("alloc/fbl/command"), Channel::new("alloc/smc/command"), Channel::new("alloc/mpc/command")];
const ACTUATION: [Channel<Actuation>; 3] =
    [Channel::new("alloc/fbl/actuation"), Channel::new("alloc/smc/actuation"), Channel::new("alloc/mpc/actuation")];

/// Stages of the simulated devices, not of the bench's services: sim-bench's
/// sensor looks for listeners on the userspace CAN bus once a second
/// (a directory scan, which allocates); real hardware has no such step.
const DEVICE_STAGES: [usize; 1] = [1];
/// The bus hand-over: iceoryx2 0.10 allocates one reference-counted state per
/// loaned sample (`ChunkMutSharedState::new`), so every publish costs exactly
/// one small allocation inside the library; nothing else on the bus allocates.
const BUS_STAGE: usize = 4;
const PUBLISHES_PER_CYCLE: u64 = 4;
/// The control step: Clarabel 0.11 allocates once per QP solve (its solve resets
/// its timers and re-creates a nested timer map), and the MPC solves one QP per
/// Gauss-Newton pass; everything of its own reuses its buffers
/// (crates/control/tests/alloc.rs pins that down for the law alone).
const CONTROL_STAGE: usize = 6;

fn assert_no_allocations(kind: Controller) {
    let mut l = Loop::new(kind);
    // Start-up: buffers grow to their working size, the MPC's solver is set up.
    for _ in 0..300 {
        l.cycle();
    }
    l.counts = [0; 9];
    let cycles = 3000;
    allocations(|| {
        for _ in 0..cycles {
            l.cycle();
        }
    });
    let ours: Vec<String> = STAGES
        .iter()
        .zip(l.counts)
        .enumerate()
        .filter(|&(i, (_, c))| {
            c > 0 && i != BUS_STAGE && !DEVICE_STAGES.contains(&i) && !(i == CONTROL_STAGE && kind == Controller::Mpc)
        })
        .map(|(_, (s, c))| format!("{s}: {c}"))
        .collect();
    assert!(ours.is_empty(), "{kind}: heap allocations in {cycles} cycles after start-up: {}", ours.join(", "));
    if kind == Controller::Mpc {
        let passes = jetbench_control::LawSettings::default().mpc.iterations as u64;
        assert!(
            l.counts[CONTROL_STAGE] <= passes * cycles,
            "MPC: {} allocations in {cycles} cycles, more than Clarabel's one per solve",
            l.counts[CONTROL_STAGE]
        );
    }
    assert_eq!(
        l.counts[BUS_STAGE],
        PUBLISHES_PER_CYCLE * cycles,
        "{kind}: the bus allocated other than iceoryx2's one allocation per loaned sample"
    );
}

#[test]
fn feedback_linearisation_loop_allocates_nothing() {
    assert_no_allocations(Controller::Fbl);
}

#[test]
fn sliding_mode_loop_allocates_nothing() {
    assert_no_allocations(Controller::Smc);
}

#[test]
fn mpc_loop_allocates_only_inside_the_qp_solver() {
    assert_no_allocations(Controller::Mpc);
}

#[test]
fn the_counter_counts() {
    let n = allocations(|| {
        let v: Vec<u64> = Vec::with_capacity(16);
        std::hint::black_box(v);
    });
    assert_eq!(n, 1);
}
