//! Thin I/O shells around the world: field-bus codecs (sans-IO) and the async servers/publishers that
//! put the simulated machine on real transports.

use serde::{Deserialize, Serialize};

/// Which buses the `serve` command brings up (all optional).
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct IoConfig {}
