//! The latency experiment behind `jetbench latency`: does the 100 Hz loop
//! hold under load on this machine?
//!
//! - [`campaign`]: one run, in rounds, under a background load: the service
//!   set over iceoryx2, the same set over Unix sockets, and the floor;
//! - [`pipeline`]: every cycle of a recorded run rebuilt from the samples'
//!   own stamps, hop by hop, into HDR histograms;
//! - [`chain`]: the machine's floor, a bare eventfd ping through four
//!   processes at the services' real-time settings;
//! - [`load`]: the background load (stress-ng, or a built-in generator);
//! - [`control_room`]: the Foxglove and Zenoh clients attached to a run, to
//!   measure what watching and commanding the bench cost the loop;
//! - [`pki`]: the control room's certificates, made with `openssl`;
//! - [`steal`]: the hypervisor's steal, sampled while measuring.
//!
//! ```no_run
//! use jetbench_latency::pipeline::analyse_pipeline;
//! use jetbench_record::Recording;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // A run recorded with `jetbench up --sim --duration 12 --record run.mcap`:
//! let analysis = analyse_pipeline(&Recording::open("run.mcap".as_ref())?, 2.0);
//! let e2e = analysis.e2e.percentiles();
//! println!("{} cycles, p50 {:.0} µs, p99 {:.0} µs, {} misses", analysis.cycles, e2e.p50, e2e.p99, analysis.deadline_misses());
//! # Ok(())
//! # }
//! ```
#![doc = include_str!("../README.md")]

pub mod campaign;
pub mod chain;
pub mod control_room;
pub mod load;
pub mod pipeline;
pub mod pki;
pub mod steal;
