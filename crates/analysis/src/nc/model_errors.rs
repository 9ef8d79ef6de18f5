//! Adapter: a [`MachineModel`] as the rewriter's [`ErrorFunction`]. Temperatures, forces and
//! strains stay at their references (offline geometric + static rewrite, Spaan Ch7 stage 1); a
//! point outside the model's configured travel has no value (`None`), so the rewriter keeps it
//! as programmed (overshoot moves).

use std::cell::RefCell;

use super::ErrorFunction;
use crate::table::Direction;
use retrocomp_model::{ErrorBreakdown, MachineModel, ModelInput, ModelState};

#[derive(Debug)]
pub struct ModelErrors<'a> {
    model: &'a MachineModel,
    /// Exact 4×4 evaluation (true) or the first-order closed form.
    exact: bool,
    scratch: RefCell<(ModelInput, ModelState, ErrorBreakdown)>,
}

impl<'a> ModelErrors<'a> {
    pub fn new(model: &'a MachineModel, exact: bool) -> Self {
        Self {
            model,
            exact,
            scratch: RefCell::new((model.new_input(), model.new_state(), model.new_breakdown())),
        }
    }
}

impl ErrorFunction for ModelErrors<'_> {
    fn error_um(&self, pos_mm: [f64; 3], dirs: [Direction; 3]) -> Option<[f64; 3]> {
        let mut s = self.scratch.borrow_mut();
        let (input, state, out) = &mut *s;
        input.pos_mm = pos_mm;
        input.dir = dirs.map(|d| if d == Direction::Forward { 1 } else { -1 });
        if self.exact {
            self.model.evaluate(input, state, out);
        } else {
            self.model.evaluate_first_order(input, state, out);
        }
        let present = self.model.axes();
        if out.flags.invalid_input || present.iter().any(|a| out.flags.outside_travel[a.index()]) {
            return None;
        }
        Some(out.total_um)
    }

    fn axes(&self) -> [bool; 3] {
        let mut a = [false; 3];
        for x in self.model.axes() {
            a[x.index()] = true;
        }
        a
    }
}
