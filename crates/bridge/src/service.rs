//! The bridge as a service of the set: started by `jetbench up --zenoh`, run
//! by the runtime's one runner as a reader of every channel.

use jetbench_msgs::ServiceId;
use jetbench_stack::runtime::{ChannelReader, Context, ServiceError, Setup};

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

impl ChannelReader for ZenohBridge {
    const ID: ServiceId = ServiceId::Bridge;

    fn open(setup: &Setup<'_>) -> Result<Self, ServiceError> {
        let endpoint: Endpoint = setup.listen.unwrap_or(DEFAULT_ENDPOINT).parse()?;
        let namespace = jetbench_bus::namespace_name()?;
        let operator = setup.config.operator.as_ref();
        let bridge = Bridge::open(setup.bus, &endpoint, &namespace, operator)?;
        tracing::info!("publishing every channel on Zenoh {endpoint} under jetbench/{namespace}/");
        if let Some(op) = operator {
            tracing::info!(
                "operator commands: anyone on jetbench/{namespace}/cmd/*; operators {} on {} \
                 (client certificate required) under jetbench/{namespace}/op/<name>/cmd/*",
                op.operators.join(", "),
                op.tls_listen
            );
        }
        Ok(ZenohBridge { bridge })
    }

    fn pump(&mut self, _ctx: &mut Context<'_>) -> Result<usize, ServiceError> {
        Ok(self.bridge.pump()?)
    }

    fn gaps(&self) -> u64 {
        self.bridge.gaps()
    }

    fn finish(&mut self) -> Result<(), ServiceError> {
        eprint!("{}", self.bridge.report());
        self.bridge.close();
        Ok(())
    }
}
