//! Unit conversion at the boundary.
//!
//! Internally retrocomp uses mm for positions, µm for translational errors, µrad for angles, °C for
//! temperatures, s for time and N for forces. Files may carry other units; they are converted exactly
//! once, when a file is read, by the functions here. A key's unit is its suffix (`forward_mm`,
//! `value_arcsec`, `value_mm_per_m`), so [`LengthUnit::from_suffix`] and [`AngleUnit::from_suffix`]
//! are the single place where suffixes are understood.

/// One arcsecond in µrad: π / (180 · 3600) rad.
pub const URAD_PER_ARCSEC: f64 = std::f64::consts::PI / 648_000.0 * 1e6;

/// Convert arcseconds to µrad.
pub fn arcsec_to_urad(arcsec: f64) -> f64 {
    arcsec * URAD_PER_ARCSEC
}

/// Convert µrad to arcseconds.
pub fn urad_to_arcsec(urad: f64) -> f64 {
    urad / URAD_PER_ARCSEC
}

/// A slope in mm per m (= µm per mm) to µrad. Small-angle: the slope is the angle in mrad.
pub fn mm_per_m_to_urad(mm_per_m: f64) -> f64 {
    mm_per_m * 1e3
}

/// Translational error in mm to µm.
pub fn mm_to_um(mm: f64) -> f64 {
    mm * 1e3
}

/// A translation unit accepted at the boundary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LengthUnit {
    Um,
    Mm,
    Nm,
}

impl LengthUnit {
    /// All accepted suffixes, for error messages.
    pub const SUFFIXES: [&'static str; 3] = ["um", "mm", "nm"];

    pub fn from_suffix(suffix: &str) -> Option<Self> {
        match suffix {
            "um" => Some(Self::Um),
            "mm" => Some(Self::Mm),
            "nm" => Some(Self::Nm),
            _ => None,
        }
    }

    /// Factor that converts a value in this unit to µm.
    pub fn to_um_factor(self) -> f64 {
        match self {
            Self::Um => 1.0,
            Self::Mm => 1e3,
            Self::Nm => 1e-3,
        }
    }
}

/// An angle unit accepted at the boundary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AngleUnit {
    Urad,
    Rad,
    Arcsec,
    /// Slope in mm per metre (Renishaw "µm/m" ÷ 1000), small-angle.
    MmPerM,
    /// Slope in µm per metre (= µrad for small angles).
    UmPerM,
}

impl AngleUnit {
    pub const SUFFIXES: [&'static str; 5] = ["urad", "rad", "arcsec", "mm_per_m", "um_per_m"];

    pub fn from_suffix(suffix: &str) -> Option<Self> {
        match suffix {
            "urad" => Some(Self::Urad),
            "rad" => Some(Self::Rad),
            "arcsec" => Some(Self::Arcsec),
            "mm_per_m" => Some(Self::MmPerM),
            "um_per_m" => Some(Self::UmPerM),
            _ => None,
        }
    }

    /// Factor that converts a value in this unit to µrad.
    pub fn to_urad_factor(self) -> f64 {
        match self {
            Self::Urad | Self::UmPerM => 1.0,
            Self::Rad => 1e6,
            Self::Arcsec => URAD_PER_ARCSEC,
            Self::MmPerM => 1e3,
        }
    }
}

/// What a channel measures, by the naming convention every channel and recording column follows
/// (`docs/recording-csv.md`): the prefix names the quantity, the suffix its unit. Read from a name
/// only here, once, when a field config or a recording is read; everything after carries the kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ChannelKind {
    /// `T_<name>_C`: a temperature, °C (latched at the thermal period; thermal terms read it).
    TemperatureC,
    /// `<name>_mm`: a length, mm (an axis position `x_mm`, the tool length `tool_mm`).
    LengthMm,
    /// `F_<name>_N`: a force, N.
    ForceN,
    /// `strain_<name>_ue`: a strain, µm/m.
    StrainUe,
    /// Any other name: a context signal (`rpm`, `load_pct`, …).
    Other,
}

impl ChannelKind {
    /// The kind of the channel named `name` (a prefix or suffix alone is not enough: `T_C`,
    /// `F__N` and `_mm` are `Other`).
    pub fn of(name: &str) -> Self {
        let framed = |prefix: &str, suffix: &str| {
            name.len() > prefix.len() + suffix.len()
                && name.starts_with(prefix)
                && name.ends_with(suffix)
        };
        if framed("T_", "_C") {
            Self::TemperatureC
        } else if framed("F_", "_N") {
            Self::ForceN
        } else if framed("strain_", "_ue") {
            Self::StrainUe
        } else if framed("", "_mm") {
            Self::LengthMm
        } else {
            Self::Other
        }
    }

    /// A force or strain channel: what the load terms read.
    pub fn is_load(self) -> bool {
        matches!(self, Self::ForceN | Self::StrainUe)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_kinds_by_the_naming_convention() {
        use ChannelKind::*;
        for (name, kind) in [
            ("T_spindle_C", TemperatureC),
            ("T_x_C", TemperatureC),
            ("x_mm", LengthMm),
            ("tool_mm", LengthMm),
            ("F_cut_N", ForceN),
            ("strain_col_ue", StrainUe),
            ("rpm", Other),
            // A prefix or suffix alone is not a kind.
            ("T_C", Other),
            ("T__C", Other),
            ("T_spindle_K", Other),
            ("F__N", Other),
            ("strain__ue", Other),
            ("_mm", Other),
            ("spindle_C", Other),
        ] {
            assert_eq!(ChannelKind::of(name), kind, "{name}");
        }
        assert!(ForceN.is_load() && StrainUe.is_load() && !TemperatureC.is_load());
    }

    #[test]
    fn arcsec_round_trip_and_known_value() {
        // 1″ = 4.8481368 µrad (definition of the arcsecond).
        assert!((arcsec_to_urad(1.0) - 4.848_136_811_095_36).abs() < 1e-12);
        assert!((urad_to_arcsec(arcsec_to_urad(-13.0)) + 13.0).abs() < 1e-12);
        // Graves §5: α = −13.0″ → −63.0 µrad.
        assert!((arcsec_to_urad(-13.0) + 63.02578).abs() < 1e-4);
    }

    #[test]
    fn slopes_and_suffixes() {
        // Asad Ullah §3.2: −0.065 mm at 170 mm = −0.38235 mm/m = −382.35 µrad.
        let slope_mm_per_m = -0.065 / 170.0 * 1000.0;
        assert!((mm_per_m_to_urad(slope_mm_per_m) + 382.352_941).abs() < 1e-5);
        assert_eq!(AngleUnit::from_suffix("mm_per_m"), Some(AngleUnit::MmPerM));
        assert_eq!(AngleUnit::from_suffix("deg"), None);
        assert_eq!(
            LengthUnit::from_suffix("mm").map(|u| u.to_um_factor()),
            Some(1e3)
        );
        assert!((mm_to_um(0.0084) - 8.4).abs() < 1e-12);
    }
}
