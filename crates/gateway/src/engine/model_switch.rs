//! Switching the machine model at run time (issue 16.2, `POST /api/model {"model": "<name>"}`).
//!
//! Only models declared in the field config can be chosen (`[gateway.models] name = "path"`,
//! paths relative to the config; each must load at start, else the config is refused with file,
//! line and key). A request names a declared model; anything else (an unknown name, a path) is
//! refused. The chosen file is read, parsed and checked OFF the cycle thread ([`Catalog::load`],
//! from the HTTP task via `spawn_blocking`): a model that no longer loads, or needs a channel the
//! box does not have, is refused with the reason and nothing changes.
//!
//! The swap itself runs through the safety ramps ([`Switcher`], on the cycle thread, between two
//! cycles): compensation is ramped out to 0 (`Engine::set_enabled(false)`: the ramp rate and the
//! per-write cap of `[safety]`), the model is replaced once every axis' output is exactly 0, then
//! compensation returns to what it was (enabled → it ramps in from 0 the same way). A
//! `POST /api/compensation` arriving meanwhile sets what it returns to. The new
//! [`ModelIdentity`] (name, sha256, loaded when) then reaches every snapshot: the page, `/status`,
//! `/metrics` and the OPC UA identification.
//!
//! Units: µm for the outputs (via the engine); times in the identity are Unix seconds.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use crate::engine::model_adapter::MachineModelAdapter;
use crate::engine::{Engine, ErrorModel};
use crate::status::ModelIdentity;
use retrocomp_model::MachineModel;

/// A declared model's name: 1–64 of `[A-Za-z0-9_-]` (never a path).
pub(crate) fn check_name(name: &str) -> Result<(), String> {
    let ok = (1..=64).contains(&name.len())
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "expected a name of 1..=64 letters, digits, '_' or '-', got {name:?}"
        ))
    }
}

/// Why a switch was refused; [`SwitchError::http_status`] maps it to a 4xx.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SwitchError {
    #[error("model {0:?} is not declared in [gateway.models] (declared: {1})")]
    NotDeclared(String, String),
    #[error("model {0:?} cannot be loaded: {1}")]
    Load(String, String),
    #[error("model {0:?} is refused: {1}")]
    Check(String, String),
}

impl SwitchError {
    pub fn http_status(&self) -> u16 {
        match self {
            SwitchError::NotDeclared(..) => 404,
            SwitchError::Load(..) | SwitchError::Check(..) => 422,
        }
    }
}

/// A loaded and checked model on its way to the cycle thread.
pub struct ModelSwap {
    /// Its name in `[gateway.models]`.
    pub name: String,
    pub identity: ModelIdentity,
    pub model: Box<dyn ErrorModel + Send>,
}

impl std::fmt::Debug for ModelSwap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModelSwap")
            .field("name", &self.name)
            .field("sha256", &self.identity.sha256)
            .finish_non_exhaustive()
    }
}

impl PartialEq for ModelSwap {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name && self.identity.sha256 == other.identity.sha256
    }
}

/// The declared models and the channels the box has (configured, delivered by a source, or
/// estimated by a recovery), for the HTTP task.
#[derive(Clone, Debug, Default)]
pub struct Catalog {
    models: BTreeMap<String, PathBuf>,
    channels: BTreeSet<String>,
}

impl Catalog {
    /// `models`: the declared models by name; `channels`: every channel the box can have.
    pub fn new(models: BTreeMap<String, PathBuf>, channels: BTreeSet<String>) -> Self {
        Catalog { models, channels }
    }

    pub fn names(&self) -> Vec<&str> {
        self.models.keys().map(String::as_str).collect()
    }

    /// Read, parse and check the declared model `name` (blocking file I/O: not on the cycle
    /// thread). `seen`: channels the engine has received so far (they count as present too).
    pub fn load(&self, name: &str, seen: &[String]) -> Result<ModelSwap, SwitchError> {
        let Some(path) = self.models.get(name) else {
            return Err(SwitchError::NotDeclared(
                name.to_string(),
                self.names().join(", "),
            ));
        };
        let model = MachineModel::from_toml_path(path)
            .map_err(|e| SwitchError::Load(name.to_string(), format!("{}: {e}", path.display())))?;
        let adapter = MachineModelAdapter::new(model);
        // A model reading a channel the box never gets would leave every axis stale.
        let missing: Vec<String> = adapter
            .required_channels()
            .into_iter()
            .map(|c| c.to_string())
            .filter(|c| !self.channels.contains(c) && !seen.contains(c))
            .collect();
        if !missing.is_empty() {
            return Err(SwitchError::Check(
                name.to_string(),
                format!(
                    "it reads channels this box does not have: {}",
                    missing.join(", ")
                ),
            ));
        }
        let identity = adapter.identity().unwrap_or_default();
        Ok(ModelSwap {
            name: name.to_string(),
            identity,
            model: Box::new(adapter),
        })
    }
}

/// A run-time action accepted on the authenticated API, for the cycle to apply. The engine
/// applies `SetCompensation` with `Engine::set_enabled`, so disabling ramps the correction to zero
/// through the same safety ramps as the `[gateway] enabled` switch. `SwitchModel` carries a model
/// already loaded and checked off the cycle thread (`model_switch.rs`: ramp out, swap, ramp in).
#[derive(Debug, PartialEq)]
pub enum Control {
    SetCompensation { enabled: bool },
    SwitchModel(Box<ModelSwap>),
}

/// The cycle side of a switch (sans-IO: the cycle loop calls it between cycles).
#[derive(Debug, Default)]
pub(crate) struct Switcher {
    pending: Option<ModelSwap>,
    /// Compensation state to return to after the swap.
    resume_enabled: bool,
}

impl Switcher {
    /// Start ramping out for `swap` (a newer request replaces a pending one).
    pub(crate) fn request(&mut self, swap: ModelSwap, engine: &mut Engine) {
        if self.pending.is_none() {
            self.resume_enabled = engine.enabled();
        }
        tracing::info!(
            model = swap.name,
            sha256 = swap.identity.sha256,
            "model switch: ramping the correction out"
        );
        self.pending = Some(swap);
        engine.set_enabled(false);
    }

    /// `POST /api/compensation` during a switch sets what compensation returns to.
    pub(crate) fn set_enabled(&mut self, enabled: bool, engine: &mut Engine) {
        if self.pending.is_some() {
            self.resume_enabled = enabled;
        } else {
            engine.set_enabled(enabled);
        }
    }

    /// The model to switch to, once every output is at 0; the engine then resolves the new
    /// model's channels at its next cycle and compensation returns (ramping in).
    pub(crate) fn poll(&mut self, engine: &mut Engine) -> Option<ModelSwap> {
        self.pending.as_ref()?;
        if !engine.outputs_at_zero() {
            return None;
        }
        let swap = self.pending.take()?;
        engine.model_replaced();
        engine.set_enabled(self.resume_enabled);
        tracing::info!(
            model = swap.name,
            sha256 = swap.identity.sha256,
            "model switch: new model in use"
        );
        Some(swap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_plain_words_never_paths() {
        for ok in ["summer", "cnc7-winter_2", "A"] {
            assert_eq!(check_name(ok), Ok(()), "{ok}");
        }
        for bad in ["", "a/b", "../x", "a.toml", "with space", &"x".repeat(65)] {
            assert!(check_name(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn an_undeclared_name_is_refused_with_the_declared_ones() {
        let mut models = BTreeMap::new();
        models.insert("geo".to_string(), PathBuf::from("/nonexistent/geo.toml"));
        let c = Catalog {
            models,
            channels: BTreeSet::new(),
        };
        let e = c.load("/etc/passwd", &[]).unwrap_err();
        assert_eq!(e.http_status(), 404);
        assert!(e.to_string().contains("declared: geo"), "{e}");
        let e = c.load("geo", &[]).unwrap_err();
        assert_eq!(e.http_status(), 422, "{e}");
    }
}
