//! A one-term error model for runtime tests that need a model but not the machine model: x's
//! error is `um_per_mm` × x (µm, error = actual − nominal), term `scale`. With `declared`, its
//! identity names the term (as the real model adapter does), so the Sparkplug birth declares it.

use retrocomp_gateway::engine::ModelError;
use retrocomp_gateway::status::ModelIdentity;
use retrocomp_gateway::{AxisErrors, ErrorModel, MachineState};
use retrocomp_model::Axis;

pub(crate) struct ScaleModel {
    pub(crate) um_per_mm: f64,
    pub(crate) declared: bool,
}

impl ErrorModel for ScaleModel {
    fn required_channels(&self) -> Vec<std::sync::Arc<str>> {
        vec![]
    }

    fn axis_errors(&mut self, s: &MachineState, out: &mut AxisErrors) -> Result<(), ModelError> {
        let x = s.position_mm(Axis::X).unwrap_or(0.0);
        out.push(Axis::X, "scale".into(), self.um_per_mm * x);
        Ok(())
    }

    fn identity(&self) -> Option<ModelIdentity> {
        self.declared.then(|| ModelIdentity {
            name: "scale".into(),
            term_groups: [("scale".to_string(), "geometric")].into(),
            ..Default::default()
        })
    }
}
