//! The bridge as a service of the set: started by `jetbench up --zenoh`, run
//! by the runtime's one runner (bus, ready, heartbeat), reading the bus on its
//! own clock.

use jetbench_bus::Wake;
use jetbench_msgs::ServiceId;
use jetbench_stack::service::{Context, Schedule, Service, ServiceError, Setup};

use crate::publish::POLL_PERIOD;
use crate::{Bridge, BridgeError, Endpoint, DEFAULT_ENDPOINT};

impl From<BridgeError> for ServiceError {
    fn from(e: BridgeError) -> Self {
        ServiceError::Other(Box::new(e))
    }
}

/// Every channel on Zenoh, listening on `--listen` (default [`DEFAULT_ENDPOINT`]).
pub struct ZenohBridge {
    bridge: Bridge,
}

impl Service for ZenohBridge {
    const ID: ServiceId = ServiceId::Bridge;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        let endpoint: Endpoint = setup.listen.unwrap_or(DEFAULT_ENDPOINT).parse()?;
        let namespace = jetbench_bus::namespace_name()?;
        let bridge = Bridge::open(setup.bus, &endpoint, &namespace)?;
        tracing::info!("publishing every channel on Zenoh {endpoint} under jetbench/{namespace}/");
        Ok((ZenohBridge { bridge }, ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::Tick(POLL_PERIOD)
    }

    fn process(&mut self, _wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        self.bridge.pump()?;
        ctx.health().set_input_gaps(self.bridge.gaps());
        ctx.cycle(false)?;
        Ok(())
    }

    fn stop(&mut self, _inputs: &(), _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        self.bridge.pump()?;
        eprint!("{}", self.bridge.report());
        self.bridge.close();
        Ok(())
    }
}
