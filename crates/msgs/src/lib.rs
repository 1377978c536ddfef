//! Fixed-layout sample types: the only types that cross process boundaries.
//!
//! Every type is `#[repr(C)]`, `Copy`, naturally aligned with no padding, and
//! starts with `seq` and `stamp_ns`. That layout is exactly the CDR encoding of
//! the ros2msg schema printed beside it, so a recorder writes a sample as the
//! 4-byte CDR header plus the struct bytes, with no serialisation code, and
//! standard tools decode it.
//!
//! ```
//! use jetbench_msgs::{Sample, Thrust};
//!
//! let mut thrust = Thrust::default();
//! thrust.thrust_n = 42.5;
//! thrust.set_seq(7);
//! let bytes = thrust.as_bytes();
//! assert_eq!(bytes.len(), std::mem::size_of::<Thrust>());
//! assert_eq!(Thrust::from_bytes(bytes), Some(thrust));
//! assert!(Thrust::schema_text().contains("float64 thrust_n"));
//! ```
//!
//! Conventions, shared by every sample:
//! - `seq` counts the samples of one publisher, contiguous from 0; a gap means loss.
//! - `stamp_ns` is the `CLOCK_MONOTONIC` time at which the originating sensor
//!   frame was received; downstream samples copy it from their input, so the
//!   end-to-end latency of any sample is `publish_ns - stamp_ns`.
//! - `source_seq` is the `seq` of the input sample a sample was computed from.
#![deny(missing_docs)]
#![doc = include_str!("../README.md")]

mod schema;

pub use schema::{cdr_layout, parse_schema, CdrField, FieldInfo, Primitive, RosType, SchemaError};

use iceoryx2::prelude::ZeroCopySend;

/// Bytes of the CDR encapsulation header for little-endian plain CDR.
pub const CDR_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Schema package used in the recorded schema names (`jetbench_msgs/msg/<Type>`).
pub const SCHEMA_PACKAGE: &str = "jetbench_msgs";

/// A fixed-layout sample that may cross processes.
///
/// Implemented only through the [`sample!`] macro of this crate, which
/// guarantees the layout properties the methods rely on.
pub trait Sample: Copy + Default + core::fmt::Debug + ZeroCopySend + 'static {
    /// Short type name, e.g. `Thrust`; also the iceoryx2 type name.
    const NAME: &'static str;
    /// The fields in declaration order, with their byte offsets.
    const FIELDS: &'static [FieldInfo];
    /// Named constants of the schema (`int32 NAME=value` lines after the
    /// fields), so a recording names the codes its samples carry.
    const CONSTANTS: &'static [SchemaConstant] = &[];

    /// Per-publisher sequence number.
    fn seq(&self) -> u64;
    /// Set by the bus publisher; samples never pick their own.
    fn set_seq(&mut self, seq: u64);
    /// Monotonic receive time of the originating sensor frame, in ns.
    fn stamp_ns(&self) -> u64;

    /// `jetbench_msgs/msg/<NAME>`: the schema name in recordings.
    fn schema_name() -> String {
        format!("{SCHEMA_PACKAGE}/msg/{}", Self::NAME)
    }

    /// The ros2msg text describing this type, one `type name` line per field.
    fn schema_text() -> String {
        let mut text = String::new();
        for field in Self::FIELDS {
            text.push_str(&field.ros_type.to_string());
            text.push(' ');
            text.push_str(field.name);
            text.push('\n');
        }
        for c in Self::CONSTANTS {
            text.push_str(&format!("{} {}={}\n", c.ros_type, c.name, c.value));
        }
        text
    }

    /// The raw bytes of the sample; equal to its CDR body.
    fn as_bytes(&self) -> &[u8] {
        // SAFETY: `sample!` types are repr(C), contain only integers and
        // floats, and have no padding (asserted at compile time), so every
        // byte is initialised.
        unsafe { core::slice::from_raw_parts((self as *const Self).cast::<u8>(), core::mem::size_of::<Self>()) }
    }

    /// The first floating-point field holding NaN or an infinity, if any. The
    /// bus refuses to publish such a sample: no consumer of a channel ever has
    /// to defend against a value that is not a number.
    fn non_finite_field(&self) -> Option<&'static str> {
        let bytes = self.as_bytes();
        for field in Self::FIELDS {
            let width = match field.ros_type.primitive() {
                Primitive::Float64 => 8,
                Primitive::Float32 => 4,
                _ => continue,
            };
            for i in 0..field.ros_type.len() {
                let at = &bytes[field.offset + i * width..];
                let finite = match width {
                    8 => at.first_chunk::<8>().is_some_and(|b| f64::from_le_bytes(*b).is_finite()),
                    _ => at.first_chunk::<4>().is_some_and(|b| f32::from_le_bytes(*b).is_finite()),
                };
                if !finite {
                    return Some(field.name);
                }
            }
        }
        None
    }

    /// Reads a sample from its raw bytes; `None` if the length is wrong.
    fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != core::mem::size_of::<Self>() {
            return None;
        }
        // SAFETY: the length matches and every bit pattern is a valid value
        // for the integer and float fields of `sample!` types.
        Some(unsafe { core::ptr::read_unaligned(bytes.as_ptr().cast::<Self>()) })
    }

    /// Reads a sample from a CDR message (4-byte header plus body).
    fn from_cdr(message: &[u8]) -> Option<Self> {
        let body = message.strip_prefix(&CDR_HEADER[..])?;
        Self::from_bytes(body)
    }
}

/// A named constant of a schema: `int32 KIND_TRIP=1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SchemaConstant {
    /// The ros2msg type, e.g. `int32`.
    pub ros_type: &'static str,
    /// The constant's name, e.g. `KIND_TRIP`.
    pub name: &'static str,
    /// Its value.
    pub value: i64,
}

/// Declares a sample type: the struct, its trait impls, its field table and
/// a compile-time proof that it has no padding; optionally the named
/// constants of its schema (`constants = PATH`, a `&[SchemaConstant]`).
macro_rules! sample {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty ),+ $(,)?
        }
    ) => {
        sample! { $(#[$meta])* pub struct $name { $( $(#[$fmeta])* pub $field : $ty ),+ } constants = &[] }
    };
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty ),+ $(,)?
        }
        constants = $constants:expr
    ) => {
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default, PartialEq, ZeroCopySend)]
        $(#[$meta])*
        pub struct $name {
            $( $(#[$fmeta])* pub $field: $ty ),+
        }

        // No padding: the struct is exactly the sum of its fields.
        const _: () = assert!(
            core::mem::size_of::<$name>() == 0 $( + core::mem::size_of::<$ty>() )+
        );

        impl Sample for $name {
            const NAME: &'static str = stringify!($name);
            const FIELDS: &'static [FieldInfo] = &[
                $( FieldInfo {
                    name: stringify!($field),
                    offset: core::mem::offset_of!($name, $field),
                    ros_type: <$ty as schema::RosField>::ROS_TYPE,
                } ),+
            ];
            const CONSTANTS: &'static [SchemaConstant] = $constants;
            fn seq(&self) -> u64 { self.seq }
            fn set_seq(&mut self, seq: u64) { self.seq = seq; }
            fn stamp_ns(&self) -> u64 { self.stamp_ns }
        }
    };
}

sample! {
    /// Calibrated thrust from the force sensor (`bench/thrust`).
    #[type_name("jetbench_msgs/msg/Thrust")]
    pub struct Thrust {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// The sensor's own frame counter.
        pub frame_seq: u64,
        /// Calibrated axial force, N.
        pub thrust_n: f64,
        /// Calibrated force on x, y, z, N.
        pub force_n: [f64; 3],
        /// Calibrated torque about x, y, z, N·m.
        pub torque_nm: [f64; 3],
        /// Sensor status bits (see [`sensor_status`]).
        pub status: u32,
        /// Sensing flags (see [`thrust_flags`]).
        pub flags: u32,
    }
}

sample! {
    /// EKF estimate of thrust and its derivatives (`bench/state`).
    #[type_name("jetbench_msgs/msg/StateEstimate")]
    pub struct StateEstimate {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// `seq` of the thrust sample this estimate used.
        pub source_seq: u64,
        /// Estimated thrust, N.
        pub thrust_n: f64,
        /// Estimated thrust rate, N/s.
        pub thrust_rate_n_per_s: f64,
        /// Estimated acceleration, N/s²: the model's at the estimate and
        /// `input_throttle_pct`, plus the estimator's disturbance (the part the model
        /// does not explain; 0 when the disturbance state is off).
        pub thrust_accel_n_per_s2: f64,
        /// Throttle the prediction step assumed was applied, %. With a model input
        /// delay the engine follows the one applied that long before: the estimator
        /// keeps the throttles in flight and predicts with that one.
        pub input_throttle_pct: f64,
        /// Measurement minus prediction, N.
        pub innovation_n: f64,
        /// Variance of the thrust estimate, N².
        pub thrust_var_n2: f64,
        /// Variance of the rate estimate, (N/s)².
        pub thrust_rate_var_n2_per_s2: f64,
        /// Estimator flags (see [`state_flags`]).
        pub flags: u64,
    }
}

sample! {
    /// The reference the controller tracks (`bench/reference`).
    #[type_name("jetbench_msgs/msg/Reference")]
    pub struct Reference {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// `seq` of the state estimate this reference was evaluated for.
        pub source_seq: u64,
        /// Time since the profile started, s.
        pub profile_time_s: f64,
        /// Reference thrust, N.
        pub thrust_n: f64,
        /// Its rate, N/s.
        pub thrust_rate_n_per_s: f64,
        /// Its acceleration, N/s².
        pub thrust_accel_n_per_s2: f64,
    }
}

sample! {
    /// Throttle command from the controller (`bench/command`).
    #[type_name("jetbench_msgs/msg/Command")]
    pub struct Command {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// `seq` of the state estimate this command was computed from.
        pub source_seq: u64,
        /// Commanded throttle, clamped to the engine range, %.
        pub throttle_pct: f64,
        /// What the control law asked for before clamping, %.
        pub unclamped_pct: f64,
        /// The control law's virtual input `v`.
        pub virtual_input: f64,
        /// Command flags (see [`command_flags`]).
        pub flags: u64,
        /// Which law computed it: 0 open loop, 1 FBL, 2 SMC, 3 MPC (the code of
        /// `jetbench_control::Controller`).
        pub controller: u32,
        /// Time the law took to compute it, µs (the MPC solve; 0 for closed-form laws).
        pub solve_us: u32,
    }
}

sample! {
    /// What the actuator applied (`bench/actuation`).
    #[type_name("jetbench_msgs/msg/Actuation")]
    pub struct Actuation {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// Monotonic time the command frame was handed to the throttle board, ns
        /// (0 when nothing was sent this cycle): the end of the control path.
        pub written_ns: u64,
        /// `seq` of the command applied (or last seen when stale).
        pub command_seq: u64,
        /// Throttle sent to the throttle board, %.
        pub applied_pct: f64,
        /// Throttle the last command asked for, %.
        pub commanded_pct: f64,
        /// Command round trip to the board, ns (0 when not measured).
        pub round_trip_ns: u64,
        /// Consecutive cycles without a fresh command.
        pub missed_cycles: u32,
        /// Actuation flags (see [`actuation_flags`]).
        pub flags: u32,
    }
}

sample! {
    /// Engine ECU telemetry (`bench/ecu`).
    #[type_name("jetbench_msgs/msg/EcuTelemetry")]
    pub struct EcuTelemetry {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// Spool speed, rpm.
        pub rpm: f64,
        /// Exhaust gas temperature, °C.
        pub egt_c: f64,
        /// Fuel pump voltage, V.
        pub pump_v: f64,
        /// Throttle position the ECU reports, %.
        pub throttle_pct: f64,
        /// The ECU's battery voltage, V, read with `RFI` every few polls (the
        /// newest reading; 0 until the first).
        pub battery_v: f64,
        /// ECU state code as reported (JetCat's RS232 number, [`ecu_states`]).
        pub state: u32,
        /// Link flags (see [`ecu_flags`]).
        pub flags: u32,
        /// Why the engine last stopped (JetCat's RS232 number, [`off_conditions`]),
        /// read with `RSS` whenever the ECU is not in run; 0 until then.
        pub off_condition: u32,
        /// Commands (start, stop) the ECU refused so far.
        pub refused: u32,
    }
}

sample! {
    /// One heartbeat per service per cycle (`bench/health`).
    #[type_name("jetbench_msgs/msg/Health")]
    pub struct Health {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// Cycles run since start.
        pub cycles: u64,
        /// Time since the previous cycle, ns.
        pub cycle_ns: u64,
        /// Work time of this cycle, ns.
        pub work_ns: u64,
        /// Longest work time so far, ns.
        pub max_work_ns: u64,
        /// Cycles whose input came later than the deadline or whose work overran the period.
        pub deadline_misses: u64,
        /// Samples lost on this service's inputs, from `seq` gaps.
        pub input_gaps: u64,
        /// Rejected inputs and failed operations.
        pub errors: u64,
        /// Which service (see [`ServiceId`]).
        pub service_id: u32,
        /// Service state bits (see [`health_flags`]).
        pub flags: u32,
    }
}

sample! {
    /// Ground truth of the simulated engine (`sim/truth`), for evaluation only.
    #[type_name("jetbench_msgs/msg/SimTruth")]
    pub struct SimTruth {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// Monotonic receive time of the originating sensor frame, ns.
        pub stamp_ns: u64,
        /// The engine's true thrust, N.
        pub thrust_n: f64,
        /// Its true rate, N/s.
        pub thrust_rate_n_per_s: f64,
        /// Throttle the engine actually followed, %.
        pub engine_throttle_pct: f64,
        /// Noise-free measurement the sensor would report, N.
        pub measured_thrust_n: f64,
        /// What injected faults added to the reading sent on the thrust axis, N
        /// (a spike's size; 0 without a fault).
        pub injected_n: f64,
        /// Faults injected into this step's sensor frame (see [`sim_faults`]).
        pub faults: u64,
    }
}

sample! {
    /// Something that happened on the bench (`bench/events`), published when
    /// it happens, not every cycle: a limit tripped or cleared, the ECU
    /// changing state, the engine shut down (with the reason), an operator
    /// command accepted or refused. The schema's constants name every code,
    /// so a recording read anywhere says what each event was.
    #[type_name("jetbench_msgs/msg/Event")]
    pub struct Event {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// When it happened (monotonic, ns); for a trip, the sample that crossed the limit.
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// The measured value behind it (for a trip, the value past the limit), else 0.
        pub value: f64,
        /// The limit it was measured against, else 0.
        pub limit: f64,
        /// What happened: one of [`event_kinds`].
        pub kind: u32,
        /// The kind's code: the new ECU state (JetCat's RS232 number, [`ecu_states`]),
        /// the off condition of a shutdown ([`off_conditions`]), the limit of a trip
        /// ([`trip_limits`]) or the operator's command ([`operator_commands`]).
        pub code: i32,
        /// Who: the publishing service ([`ServiceId`]) or, for an operator
        /// command, the id of the client that sent it.
        pub source_id: u32,
        /// What came before or why: the previous ECU state of an `ECU_STATE`
        /// event, the reason of a `COMMAND_REFUSED` ([`refusals`]), the limit or
        /// off condition behind a `TEST_ENDED`; 0 otherwise.
        pub previous: i32,
        /// For an operator command, where it came from ([`origins`]); 0 otherwise.
        pub origin: u32,
        /// For an operator command, the authority its gateway vouched for ([`authorities`]).
        pub authority: u32,
        /// For an operator command, who sent it (UTF-8, NUL-padded: a certificate's
        /// common name, `local:<user>`); else the publishing service's name.
        pub identity: [u8; IDENTITY_LEN],
    }
    constants = EVENT_CONSTANTS
}

sample! {
    /// An operator's command to the bench (`bench/operator`): from this machine's
    /// command line or from a gateway of the control room, which authenticated
    /// the sender and says so in `authority`. The control service is its only
    /// consumer and decides; it answers each with a `COMMAND_ACCEPTED` or
    /// `COMMAND_REFUSED` event on `bench/events` naming the sender.
    #[type_name("jetbench_msgs/msg/OperatorCommand")]
    pub struct OperatorCommand {
        /// Per-publisher sequence number (module docs).
        pub seq: u64,
        /// When the operator gave it (monotonic, ns).
        pub stamp_ns: u64,
        /// Monotonic time this sample was published, ns.
        pub publish_ns: u64,
        /// The command's argument: the reference in N (`SET_REFERENCE`), the
        /// profile index (`RUN_PROFILE`), the throttle in % (`HOLD`); else 0.
        pub value: f64,
        /// What to do: one of [`operator_commands`].
        pub command: i32,
        /// Where it came from: one of [`origins`].
        pub origin: u32,
        /// The gateway's id for the client (0 for a local command).
        pub client_id: u32,
        /// What the gateway that authenticated the sender vouches for: one of
        /// [`authorities`]. Commands given on the bench PC itself are `OPERATOR`.
        pub authority: u32,
        /// Who sent it (UTF-8, NUL-padded): the certificate's common name,
        /// `local:<user>`, ...
        pub identity: [u8; IDENTITY_LEN],
    }
    constants = OPERATOR_CONSTANTS
}

/// Bytes of the `identity` of [`OperatorCommand`] and [`Event`].
pub const IDENTITY_LEN: usize = 32;

/// `text` as a NUL-padded identity, cut at a character boundary to fit.
pub fn identity(text: &str) -> [u8; IDENTITY_LEN] {
    let mut out = [0u8; IDENTITY_LEN];
    let mut end = text.len().min(IDENTITY_LEN);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    out[..end].copy_from_slice(&text.as_bytes()[..end]);
    out
}

/// The text of a NUL-padded identity (invalid UTF-8 replaced, never a panic).
pub fn identity_text(bytes: &[u8; IDENTITY_LEN]) -> String {
    let end = bytes.iter().position(|b| *b == 0).unwrap_or(IDENTITY_LEN);
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// Kinds of [`Event`].
pub mod event_kinds {
    /// A limit tripped: `code` is the limit ([`super::trip_limits`]).
    pub const TRIP: u32 = 1;
    /// The operator cleared the latched trips.
    pub const TRIP_CLEARED: u32 = 2;
    /// The ECU changed state: `code` the new one, `previous` the old ([`super::ecu_states`]).
    pub const ECU_STATE: u32 = 3;
    /// The engine shut down: `code` is the off condition ([`super::off_conditions`]).
    pub const SHUTDOWN: u32 = 4;
    /// An operator command was accepted: `code` is the command ([`super::operator_commands`]).
    pub const COMMAND_ACCEPTED: u32 = 5;
    /// An operator command was refused (not authorised, or not possible now).
    pub const COMMAND_REFUSED: u32 = 6;
    /// The test is over and the engine is being brought down: `code` is why
    /// ([`super::end_reasons`]); for a trip `previous` names the limit, for a
    /// shutdown the ECU made `previous` is its off condition.
    pub const TEST_ENDED: u32 = 7;
    /// The deadman idled the engine: the operator holding control was silent longer
    /// than the window while the engine ran above idle. `identity` is the operator,
    /// `value` how long they had been silent, s, `limit` the window, s. Latched: the
    /// engine stays at idle until an operator in control raises it again.
    pub const DEADMAN: u32 = 8;
    /// Control moved (taken, released, offered, handed over): `code` is the command
    /// that moved it ([`super::operator_commands`]), `identity` the holder now (empty
    /// when nobody holds it), `previous` 1 when it was taken from a lapsed holder.
    pub const CONTROL: u32 = 9;
}

/// Why an operator command was refused (`previous` of a `COMMAND_REFUSED` event).
pub mod refusals {
    /// It could raise the throttle, and its sender is not an authenticated operator.
    pub const NOT_AUTHORISED: i32 = 1;
    /// Not possible in the engine's state (e.g. a start while the ECU is not in standby).
    pub const NOT_NOW: i32 = 2;
    /// The test has ended: the engine is being brought down.
    pub const TEST_ENDED: i32 = 3;
    /// Its value is out of range (a profile index, a reference, a throttle).
    pub const BAD_VALUE: i32 = 4;
    /// A command code this bench does not know.
    pub const UNKNOWN: i32 = 5;
    /// Trips are latched: clear them first.
    pub const TRIPPED: i32 = 6;
    /// Another operator holds control and their link is alive.
    pub const HELD_BY_ANOTHER: i32 = 7;
    /// It is the holder's to send (a raising command, release, heartbeat), and the
    /// sender does not hold control: take it first.
    pub const NOT_IN_CONTROL: i32 = 8;
    /// A handover was accepted with no open offer.
    pub const NO_HANDOVER_OFFER: i32 = 9;
}

/// Why a test ended ([`event_kinds::TEST_ENDED`]'s code).
pub mod end_reasons {
    /// An operator stopped it (`STOP` or `STOP_NOW`).
    pub const OPERATOR: i32 = 1;
    /// The ECU left run on its own (`previous` is its off condition).
    pub const ECU_SHUTDOWN: i32 = 2;
    /// A limit whose response is `shutdown` tripped (`previous` is the limit).
    pub const TRIP: i32 = 3;
}

/// Limits a trip names (the `[limits]` of the bench config).
pub mod trip_limits {
    /// `max_thrust_n`: the measured thrust above its limit.
    pub const MAX_THRUST: i32 = 1;
    /// `max_egt_c`: the exhaust gas temperature above its limit.
    pub const MAX_EGT: i32 = 2;
    /// `max_egt_rise_c_per_s`: the exhaust heating faster than its limit.
    pub const MAX_EGT_RISE: i32 = 3;
    /// `max_rpm`: the spool above its speed limit.
    pub const MAX_RPM: i32 = 4;
    /// `min_rpm`: the spool below its speed limit while running.
    pub const MIN_RPM: i32 = 5;
    /// `thrust_rpm_band_n`: the measured thrust outside the band the RPM implies.
    pub const THRUST_RPM_MISMATCH: i32 = 6;
    /// `ecu_silent_s`: no ECU telemetry for longer than its limit.
    pub const ECU_SILENT: i32 = 7;
    /// `sensor_silent_s`: no thrust sample for longer than its limit.
    pub const SENSOR_SILENT: i32 = 8;
}

/// Operator commands ([`OperatorCommand`]'s `command`).
///
/// Safe commands (`HOLD` at or below the current throttle, `IDLE`, `STOP`,
/// `STOP_NOW`, `HEARTBEAT`, `RELEASE_CONTROL`) are accepted from any authority;
/// the ones that can raise the throttle (`START`, `RUN_PROFILE`, `SET_REFERENCE`
/// above the current, `CLEAR_TRIPS`, `TAKE_CONTROL`, `HANDOVER`) only from
/// [`authorities::OPERATOR`].
pub mod operator_commands {
    /// Start the engine through the ECU.
    pub const START: i32 = 1;
    /// Idle, then shut down through the ECU with its cool-down.
    pub const STOP: i32 = 2;
    /// Shut down at once (the emergency stop).
    pub const STOP_NOW: i32 = 3;
    /// Clear the latched trips.
    pub const CLEAR_TRIPS: i32 = 4;
    /// Hold at or below the current throttle (`value`, %; 0 = the current).
    pub const HOLD: i32 = 5;
    /// Go to idle and stay there.
    pub const IDLE: i32 = 6;
    /// Run a profile: `value` is its index in `jetbench_control::BUILTIN_PROFILES`
    /// (0 steps, 1 ramps, 2 sines, 3 chirp, 4 campaign), scaled to the model's
    /// thrust range; -1 is the bench config's own `[reference]`.
    pub const RUN_PROFILE: i32 = 7;
    /// Track a constant reference: `value` in N.
    pub const SET_REFERENCE: i32 = 8;
    /// Take the operator's lease (free, or its holder's heartbeats lapsed).
    pub const TAKE_CONTROL: i32 = 9;
    /// Give the operator's lease up.
    pub const RELEASE_CONTROL: i32 = 10;
    /// Offer the lease to another operator, or accept one offered.
    pub const HANDOVER: i32 = 11;
    /// The lease holder is still there (the deadman counts from the last one).
    pub const HEARTBEAT: i32 = 12;

    /// The command's name (`STOP_NOW`), or `None` for an unknown code.
    pub fn name(code: i32) -> Option<&'static str> {
        Some(match code {
            START => "START",
            STOP => "STOP",
            STOP_NOW => "STOP_NOW",
            CLEAR_TRIPS => "CLEAR_TRIPS",
            HOLD => "HOLD",
            IDLE => "IDLE",
            RUN_PROFILE => "RUN_PROFILE",
            SET_REFERENCE => "SET_REFERENCE",
            TAKE_CONTROL => "TAKE_CONTROL",
            RELEASE_CONTROL => "RELEASE_CONTROL",
            HANDOVER => "HANDOVER",
            HEARTBEAT => "HEARTBEAT",
            _ => return None,
        })
    }
}

/// Where an [`OperatorCommand`] came from.
pub mod origins {
    /// The bench PC's own command line (`jetbench stop`, Ctrl-C in `jetbench up`).
    pub const LOCAL: u32 = 1;
    /// The Zenoh gateway to the control room.
    pub const ZENOH: u32 = 2;
    /// The Foxglove live view's gateway.
    pub const FOXGLOVE: u32 = 3;
}

/// The authority a gateway vouches for in an [`OperatorCommand`].
pub mod authorities {
    /// Anyone: only safe commands are accepted.
    pub const ANYONE: u32 = 0;
    /// An operator: authenticated by a trusted client certificate or token, or
    /// on the bench PC itself.
    pub const OPERATOR: u32 = 1;
}

/// The ECU states by JetCat's RS232 number (the state field of `bench/ecu`
/// and of ECU-state events); named in crates/io's `ecu::state::EcuState`.
pub mod ecu_states {
    /// State 0: off.
    pub const OFF: i32 = 0;
    /// State 1: standby.
    pub const STANDBY: i32 = 1;
    /// State 2: ignite.
    pub const IGNITE: i32 = 2;
    /// State 3: accelerate.
    pub const ACCELERATE: i32 = 3;
    /// State 4: stabilise.
    pub const STABILISE: i32 = 4;
    /// State 5: learn high.
    pub const LEARN_HIGH: i32 = 5;
    /// State 6: learn low.
    pub const LEARN_LOW: i32 = 6;
    /// State 8: slow-down.
    pub const SLOW_DOWN: i32 = 8;
    /// State 10: auto-off.
    pub const AUTO_OFF: i32 = 10;
    /// State 11: run.
    pub const RUN: i32 = 11;
    /// State 12: acceleration delay.
    pub const ACCELERATION_DELAY: i32 = 12;
    /// State 13: speed control.
    pub const SPEED_CONTROL: i32 = 13;
    /// State 14: two-shaft regulate.
    pub const TWO_SHAFT_REGULATE: i32 = 14;
    /// State 15: preheat 1.
    pub const PREHEAT_1: i32 = 15;
    /// State 16: preheat 2.
    pub const PREHEAT_2: i32 = 16;
    /// State 17: main fuel start.
    pub const MAIN_FUEL_START: i32 = 17;
    /// State 19: kerosene full on.
    pub const KEROSENE_FULL_ON: i32 = 19;
}

/// The ECU's off conditions by JetCat's RS232 number (the `RSS` reply);
/// named in crates/io's `ecu::state::OffCondition`.
pub mod off_conditions {
    /// Off condition 0: none.
    pub const NONE: i32 = 0;
    /// Off condition 1: shut down via R/C.
    pub const RC_OFF: i32 = 1;
    /// Off condition 2: over-temperature.
    pub const OVER_TEMPERATURE: i32 = 2;
    /// Off condition 3: ignition time-out.
    pub const IGNITION_TIMEOUT: i32 = 3;
    /// Off condition 4: acceleration time-out.
    pub const ACCELERATION_TIMEOUT: i32 = 4;
    /// Off condition 5: acceleration too slow.
    pub const ACCELERATION_TOO_SLOW: i32 = 5;
    /// Off condition 6: over-RPM.
    pub const OVER_RPM: i32 = 6;
    /// Off condition 7: low RPM (flame-out).
    pub const LOW_RPM: i32 = 7;
    /// Off condition 8: low battery.
    pub const LOW_BATTERY: i32 = 8;
    /// Off condition 9: auto-off.
    pub const AUTO_OFF: i32 = 9;
    /// Off condition 10: low temperature.
    pub const LOW_TEMPERATURE: i32 = 10;
    /// Off condition 11: high temperature.
    pub const HIGH_TEMPERATURE: i32 = 11;
    /// Off condition 12: glow plug defective.
    pub const GLOW_PLUG: i32 = 12;
    /// Off condition 13: watchdog.
    pub const WATCHDOG: i32 = 13;
    /// Off condition 14: fail-safe.
    pub const FAIL_SAFE: i32 = 14;
    /// Off condition 15: manual off.
    pub const MANUAL_OFF: i32 = 15;
    /// Off condition 16: power fail.
    pub const POWER_FAIL: i32 = 16;
    /// Off condition 17: temperature sensor failed.
    pub const TEMP_SENSOR_FAIL: i32 = 17;
    /// Off condition 18: fuel fail.
    pub const FUEL_FAIL: i32 = 18;
    /// Off condition 19: propeller fail.
    pub const PROP_FAIL: i32 = 19;
    /// Off condition 20: second engine failed.
    pub const SECOND_ENGINE_FAIL: i32 = 20;
    /// Off condition 21: second engine difference too high.
    pub const SECOND_ENGINE_DIFFERENCE: i32 = 21;
    /// Off condition 22: second engine not communicating.
    pub const SECOND_ENGINE_SILENT: i32 = 22;
}

macro_rules! constants {
    ($( $module:ident :: $name:ident as $prefix:literal : $ty:literal ),* $(,)?) => {
        &[$( SchemaConstant { ros_type: $ty, name: concat!($prefix, stringify!($name)), value: $module::$name as i64 } ),*]
    };
}

/// The named codes in [`Event`]'s schema, prefixed by what they name
/// (`KIND_`, `LIMIT_`, `COMMAND_`, `ECU_`, `OFF_`).
pub const EVENT_CONSTANTS: &[SchemaConstant] = constants![
    event_kinds::TRIP as "KIND_": "uint32",
    event_kinds::TRIP_CLEARED as "KIND_": "uint32",
    event_kinds::ECU_STATE as "KIND_": "uint32",
    event_kinds::SHUTDOWN as "KIND_": "uint32",
    event_kinds::COMMAND_ACCEPTED as "KIND_": "uint32",
    event_kinds::COMMAND_REFUSED as "KIND_": "uint32",
    event_kinds::TEST_ENDED as "KIND_": "uint32",
    event_kinds::DEADMAN as "KIND_": "uint32",
    event_kinds::CONTROL as "KIND_": "uint32",
    end_reasons::OPERATOR as "END_": "int32",
    end_reasons::ECU_SHUTDOWN as "END_": "int32",
    end_reasons::TRIP as "END_": "int32",
    refusals::NOT_AUTHORISED as "REFUSED_": "int32",
    refusals::NOT_NOW as "REFUSED_": "int32",
    refusals::TEST_ENDED as "REFUSED_": "int32",
    refusals::BAD_VALUE as "REFUSED_": "int32",
    refusals::UNKNOWN as "REFUSED_": "int32",
    refusals::TRIPPED as "REFUSED_": "int32",
    refusals::HELD_BY_ANOTHER as "REFUSED_": "int32",
    refusals::NOT_IN_CONTROL as "REFUSED_": "int32",
    refusals::NO_HANDOVER_OFFER as "REFUSED_": "int32",
    trip_limits::MAX_THRUST as "LIMIT_": "int32",
    trip_limits::MAX_EGT as "LIMIT_": "int32",
    trip_limits::MAX_EGT_RISE as "LIMIT_": "int32",
    trip_limits::MAX_RPM as "LIMIT_": "int32",
    trip_limits::MIN_RPM as "LIMIT_": "int32",
    trip_limits::THRUST_RPM_MISMATCH as "LIMIT_": "int32",
    trip_limits::ECU_SILENT as "LIMIT_": "int32",
    trip_limits::SENSOR_SILENT as "LIMIT_": "int32",
    operator_commands::START as "COMMAND_": "int32",
    operator_commands::STOP as "COMMAND_": "int32",
    operator_commands::STOP_NOW as "COMMAND_": "int32",
    operator_commands::CLEAR_TRIPS as "COMMAND_": "int32",
    operator_commands::HOLD as "COMMAND_": "int32",
    operator_commands::IDLE as "COMMAND_": "int32",
    operator_commands::RUN_PROFILE as "COMMAND_": "int32",
    operator_commands::SET_REFERENCE as "COMMAND_": "int32",
    operator_commands::TAKE_CONTROL as "COMMAND_": "int32",
    operator_commands::RELEASE_CONTROL as "COMMAND_": "int32",
    operator_commands::HANDOVER as "COMMAND_": "int32",
    operator_commands::HEARTBEAT as "COMMAND_": "int32",
    origins::LOCAL as "ORIGIN_": "uint32",
    origins::ZENOH as "ORIGIN_": "uint32",
    origins::FOXGLOVE as "ORIGIN_": "uint32",
    authorities::ANYONE as "AUTHORITY_": "uint32",
    authorities::OPERATOR as "AUTHORITY_": "uint32",
    ecu_states::OFF as "ECU_": "int32",
    ecu_states::STANDBY as "ECU_": "int32",
    ecu_states::IGNITE as "ECU_": "int32",
    ecu_states::ACCELERATE as "ECU_": "int32",
    ecu_states::STABILISE as "ECU_": "int32",
    ecu_states::LEARN_HIGH as "ECU_": "int32",
    ecu_states::LEARN_LOW as "ECU_": "int32",
    ecu_states::SLOW_DOWN as "ECU_": "int32",
    ecu_states::AUTO_OFF as "ECU_": "int32",
    ecu_states::RUN as "ECU_": "int32",
    ecu_states::ACCELERATION_DELAY as "ECU_": "int32",
    ecu_states::SPEED_CONTROL as "ECU_": "int32",
    ecu_states::TWO_SHAFT_REGULATE as "ECU_": "int32",
    ecu_states::PREHEAT_1 as "ECU_": "int32",
    ecu_states::PREHEAT_2 as "ECU_": "int32",
    ecu_states::MAIN_FUEL_START as "ECU_": "int32",
    ecu_states::KEROSENE_FULL_ON as "ECU_": "int32",
    off_conditions::NONE as "OFF_": "int32",
    off_conditions::RC_OFF as "OFF_": "int32",
    off_conditions::OVER_TEMPERATURE as "OFF_": "int32",
    off_conditions::IGNITION_TIMEOUT as "OFF_": "int32",
    off_conditions::ACCELERATION_TIMEOUT as "OFF_": "int32",
    off_conditions::ACCELERATION_TOO_SLOW as "OFF_": "int32",
    off_conditions::OVER_RPM as "OFF_": "int32",
    off_conditions::LOW_RPM as "OFF_": "int32",
    off_conditions::LOW_BATTERY as "OFF_": "int32",
    off_conditions::AUTO_OFF as "OFF_": "int32",
    off_conditions::LOW_TEMPERATURE as "OFF_": "int32",
    off_conditions::HIGH_TEMPERATURE as "OFF_": "int32",
    off_conditions::GLOW_PLUG as "OFF_": "int32",
    off_conditions::WATCHDOG as "OFF_": "int32",
    off_conditions::FAIL_SAFE as "OFF_": "int32",
    off_conditions::MANUAL_OFF as "OFF_": "int32",
    off_conditions::POWER_FAIL as "OFF_": "int32",
    off_conditions::TEMP_SENSOR_FAIL as "OFF_": "int32",
    off_conditions::FUEL_FAIL as "OFF_": "int32",
    off_conditions::PROP_FAIL as "OFF_": "int32",
    off_conditions::SECOND_ENGINE_FAIL as "OFF_": "int32",
    off_conditions::SECOND_ENGINE_DIFFERENCE as "OFF_": "int32",
    off_conditions::SECOND_ENGINE_SILENT as "OFF_": "int32",
];

/// The named codes in [`OperatorCommand`]'s schema (`COMMAND_`, `ORIGIN_`, `AUTHORITY_`).
pub const OPERATOR_CONSTANTS: &[SchemaConstant] = constants![
    operator_commands::START as "COMMAND_": "int32",
    operator_commands::STOP as "COMMAND_": "int32",
    operator_commands::STOP_NOW as "COMMAND_": "int32",
    operator_commands::CLEAR_TRIPS as "COMMAND_": "int32",
    operator_commands::HOLD as "COMMAND_": "int32",
    operator_commands::IDLE as "COMMAND_": "int32",
    operator_commands::RUN_PROFILE as "COMMAND_": "int32",
    operator_commands::SET_REFERENCE as "COMMAND_": "int32",
    operator_commands::TAKE_CONTROL as "COMMAND_": "int32",
    operator_commands::RELEASE_CONTROL as "COMMAND_": "int32",
    operator_commands::HANDOVER as "COMMAND_": "int32",
    operator_commands::HEARTBEAT as "COMMAND_": "int32",
    origins::LOCAL as "ORIGIN_": "uint32",
    origins::ZENOH as "ORIGIN_": "uint32",
    origins::FOXGLOVE as "ORIGIN_": "uint32",
    authorities::ANYONE as "AUTHORITY_": "uint32",
    authorities::OPERATOR as "AUTHORITY_": "uint32",
];

/// Sensor status bits, as in the CAN protocol (byte 7).
pub mod sensor_status {
    /// A force or torque beyond the sensor's range.
    pub const OVERLOAD: u32 = 1 << 0;
    /// The sensor's temperature outside its compensated range.
    pub const TEMPERATURE_WARNING: u32 = 1 << 1;
    /// The sensor's calibration data failed its check.
    pub const CALIBRATION_INVALID: u32 = 1 << 2;
}

/// Faults injected into the simulated sensor (`jetbench up --sim --inject`), as
/// [`SimTruth`](crate::SimTruth) marks them.
pub mod sim_faults {
    /// The reading was off by a spike (`injected_n`).
    pub const SPIKE: u64 = 1 << 0;
    /// The sensor repeated an earlier reading.
    pub const STUCK: u64 = 1 << 1;
    /// The reading was not a number (it enters at sensing's decoder).
    pub const NAN: u64 = 1 << 2;
    /// The sensor sent nothing.
    pub const SILENCE: u64 = 1 << 3;
    /// The reading was shifted by a constant (a mount or calibration fault, `injected_n`).
    pub const OFFSET: u64 = 1 << 4;
}

/// Flags of [`Thrust`](crate::Thrust).
pub mod thrust_flags {
    /// The sensor reported a status bit.
    pub const SENSOR_STATUS: u32 = 1 << 0;
    /// Frames were lost before this one.
    pub const FRAME_GAP: u32 = 1 << 1;
    /// The first sample after the sensor was silent for at least one input
    /// deadline (sensing reported it in `bench/health` meanwhile).
    pub const SENSOR_RESUMED: u32 = 1 << 2;
}

/// Flags of [`StateEstimate`](crate::StateEstimate).
pub mod state_flags {
    /// The model prediction was unusable and a constant-rate prediction was used.
    pub const MODEL_FALLBACK: u64 = 1 << 0;
    /// No actuation sample has been seen yet; the idle throttle was assumed.
    pub const INPUT_ASSUMED: u64 = 1 << 1;
    /// The thrust measurement was implausible (a spike: its innovation failed the
    /// chi-square gate) and was not used; the estimate is the model's prediction.
    pub const MEASUREMENT_REJECTED: u64 = 1 << 2;
    /// The sensor repeats the same reading (stuck); its readings are not used.
    pub const SENSOR_STUCK: u64 = 1 << 3;
    /// Measurements were rejected too often in a row: the filter restarted at this one.
    pub const FILTER_RESTARTED: u64 = 1 << 4;
    /// The rate estimate is still settling after the filter started or restarted: it
    /// follows the measurements' first differences more than the model. A closed-loop law
    /// about to start waits for it to clear, the throttle held where it was.
    pub const SETTLING: u64 = 1 << 5;
}

/// Flags of [`Command`](crate::Command).
pub mod command_flags {
    /// The law asked for less than idle; the command is idle.
    pub const SATURATED_LOW: u64 = 1 << 0;
    /// The law asked for more than full throttle; the command is full throttle.
    pub const SATURATED_HIGH: u64 = 1 << 1;
    /// The configured law failed this cycle (an MPC solve that did not converge in
    /// time); feedback linearisation computed the command instead.
    pub const FALLBACK: u64 = 1 << 2;
    /// The throttle is held at idle (or below a hold) whatever the law asked:
    /// the ECU is not in run, a trip is latched, or an operator said idle or hold;
    /// or held where it was while a law about to start waits for the estimate to settle
    /// (`state_flags::SETTLING`).
    pub const GATED: u64 = 1 << 3;
    /// Control asks actuation to start the engine through the ECU.
    pub const ECU_START: u64 = 1 << 4;
    /// Control asks actuation to shut the engine down through the ECU.
    pub const ECU_STOP: u64 = 1 << 5;
    /// The law was started afresh for this command (integral, shaper, predictor
    /// and profile time): its output reaches the engine again after being held
    /// at idle, or the operator chose a new profile. A replay of the controller
    /// resets its law at this command too.
    pub const LAW_RESET: u64 = 1 << 6;
}

/// Flags of [`Actuation`](crate::Actuation).
pub mod actuation_flags {
    /// No fresh command for the allowed number of cycles: idle commanded.
    pub const IDLE_FALLBACK: u32 = 1 << 0;
    /// This cycle had no fresh command; the last one was held.
    pub const STALE: u32 = 1 << 1;
    /// The board has not acknowledged this cycle's command (yet); `applied_pct`
    /// is the newest acknowledged value.
    pub const UNACKED: u32 = 1 << 2;
    /// Nothing heard from the board for 3 or more cycles: it is silent, its port
    /// is being reopened, and `applied_pct` is idle (the board's own watchdog).
    pub const BOARD_SILENT: u32 = 1 << 3;
    /// The board reports it idles by its own watchdog.
    pub const BOARD_IDLE: u32 = 1 << 4;
    /// Actuation's last sample: it stopped, and the board acknowledged the disarm
    /// (the engine is at idle, `applied_pct` says so, and no command is applied
    /// until the board is armed again).
    pub const DISARMED: u32 = 1 << 5;
}

/// Flags of [`EcuTelemetry`](crate::EcuTelemetry).
pub mod ecu_flags {
    /// This poll got no valid reply; the values are the last valid ones.
    pub const STALE: u32 = 1 << 0;
    /// No valid reply for 3 or more polls: the ECU is silent and its port is being reopened.
    pub const SILENT: u32 = 1 << 1;
}

/// Flags of [`Health`](crate::Health).
pub mod health_flags {
    /// The service's input is overdue.
    pub const INPUT_OVERDUE: u32 = 1 << 0;
    /// The service is in a fallback mode (e.g. actuation at idle).
    pub const FALLBACK: u32 = 1 << 1;
}

/// Identifies the sender of a [`Health`] heartbeat.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ServiceId {
    /// The simulated bench (engine, sensor, board, ECU).
    SimBench = 1,
    /// Force sensor frames to thrust.
    Sensing = 2,
    /// The thrust observer.
    Estimation = 3,
    /// The controller and the engine supervisor.
    Control = 4,
    /// The throttle board and the ECU's commands.
    Actuation = 5,
    /// Every channel to MCAP.
    Recorder = 6,
    /// The Foxglove live view (off the control path).
    Viewer = 7,
    /// The Zenoh bridge to other machines (off the control path).
    Bridge = 8,
}

impl ServiceId {
    /// Every service, in id order.
    pub const ALL: [ServiceId; 8] = [
        ServiceId::SimBench,
        ServiceId::Sensing,
        ServiceId::Estimation,
        ServiceId::Control,
        ServiceId::Actuation,
        ServiceId::Recorder,
        ServiceId::Viewer,
        ServiceId::Bridge,
    ];

    /// The service's name, also its binary's suffix (`jetbench-<name>`).
    pub fn name(self) -> &'static str {
        match self {
            ServiceId::SimBench => "sim-bench",
            ServiceId::Sensing => "sensing",
            ServiceId::Estimation => "estimation",
            ServiceId::Control => "control",
            ServiceId::Actuation => "actuation",
            ServiceId::Recorder => "recorder",
            ServiceId::Viewer => "viewer",
            ServiceId::Bridge => "bridge",
        }
    }

    /// The service of a heartbeat's id; `None` for an unknown one.
    pub fn from_u32(id: u32) -> Option<ServiceId> {
        Self::ALL.into_iter().find(|s| *s as u32 == id)
    }
}

/// A named bus channel carrying samples of type `T`.
#[derive(Debug)]
pub struct Channel<T> {
    /// Bus service name, e.g. `bench/thrust`; the recorded topic is `/` + name.
    pub name: &'static str,
    /// Publishers the channel admits at once. Every publish and every receive
    /// walks this many slots, so it is kept to what the channel needs.
    pub max_publishers: usize,
    _type: core::marker::PhantomData<fn() -> T>,
}

impl<T> Clone for Channel<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Channel<T> {}

impl<T: Sample> Channel<T> {
    /// A channel with one publisher (and room for a restarted one while the
    /// bus has not yet cleaned up after the process it replaces).
    pub const fn new(name: &'static str) -> Self {
        Self::with_publishers(name, 2)
    }

    /// A channel that `max_publishers` processes publish on at once.
    pub const fn with_publishers(name: &'static str, max_publishers: usize) -> Self {
        Channel { name, max_publishers, _type: core::marker::PhantomData }
    }

    /// The MCAP topic: `/bench/thrust` for `bench/thrust`.
    pub fn topic(&self) -> String {
        format!("/{}", self.name)
    }
}

/// The channels of the service set.
pub mod channels {
    use super::*;

    /// Measured thrust, from sensing.
    pub const THRUST: Channel<Thrust> = Channel::new("bench/thrust");
    /// The estimated thrust and rate, from estimation.
    pub const STATE: Channel<StateEstimate> = Channel::new("bench/state");
    /// The reference the controller tracks.
    pub const REFERENCE: Channel<Reference> = Channel::new("bench/reference");
    /// The throttle command, from control.
    pub const COMMAND: Channel<Command> = Channel::new("bench/command");
    /// The throttle applied by the board, from actuation.
    pub const ACTUATION: Channel<Actuation> = Channel::new("bench/actuation");
    /// The engine ECU's telemetry, from actuation.
    pub const ECU: Channel<EcuTelemetry> = Channel::new("bench/ecu");
    /// One publisher per service (see [`ServiceId::ALL`]), and two spare.
    pub const HEALTH: Channel<Health> = Channel::with_publishers("bench/health", ServiceId::ALL.len() + 2);
    /// What the simulated engine really did (the simulated bench only).
    pub const SIM_TRUTH: Channel<SimTruth> = Channel::new("sim/truth");
    /// Trips, ECU state changes, shutdowns, operator commands: published by
    /// several services (control, actuation, the launcher), so room for each.
    pub const EVENTS: Channel<Event> = Channel::with_publishers("bench/events", ServiceId::ALL.len() + 2);
    /// Operator commands: from the command line (one short-lived process per
    /// command) and the control room's gateways; the control service consumes them.
    pub const OPERATOR: Channel<OperatorCommand> = Channel::with_publishers("bench/operator", 8);
}

/// Calls a generic visitor once per channel with its static type.
///
/// Code that must handle every channel (the recorder, `echo`, `hz`) uses this
/// instead of its own list, so a new channel cannot be forgotten.
pub trait ChannelVisitor {
    /// Called once per channel.
    fn visit<T: Sample>(&mut self, channel: Channel<T>);
}

/// Visits every channel of the service set, bench channels first.
pub fn visit_channels<V: ChannelVisitor>(visitor: &mut V) {
    use channels::*;
    visitor.visit(THRUST);
    visitor.visit(STATE);
    visitor.visit(REFERENCE);
    visitor.visit(COMMAND);
    visitor.visit(ACTUATION);
    visitor.visit(ECU);
    visitor.visit(HEALTH);
    visitor.visit(EVENTS);
    visitor.visit(OPERATOR);
    visitor.visit(SIM_TRUTH);
}

/// Names of every channel, in [`visit_channels`] order.
pub fn channel_names() -> Vec<&'static str> {
    struct Names(Vec<&'static str>);
    impl ChannelVisitor for Names {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            self.0.push(channel.name);
        }
    }
    let mut names = Names(Vec::new());
    visit_channels(&mut names);
    names.0
}

/// Formats a sample as `name=value` pairs in field order, for `echo`.
pub fn format_fields<T: Sample>(sample: &T) -> String {
    let bytes = sample.as_bytes();
    let mut out = String::new();
    for (i, field) in T::FIELDS.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        out.push_str(field.name);
        out.push('=');
        out.push_str(&field.ros_type.format_value(&bytes[field.offset..]));
    }
    out
}
