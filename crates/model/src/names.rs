//! Error-component names: ISO 230-1 inside retrocomp, and the ONE place where the seeds' names map
//! onto them.
//!
//! ISO 230-1 names a linear axis K's six error motions EXK, EYK, EZK (translations along X, Y, Z) and
//! EAK, EBK, ECK (rotations about X, Y, Z); squareness errors are EC0Y (X–Y), EB0Z (X–Z), EA0Z (Y–Z).
//!
//! | seed | their name | meaning | ISO 230-1 |
//! |---|---|---|---|
//! | Asad Ullah 2013, ASME B5.54 style | `δab` (`dab`) | translation along a while b moves | `E{A}{B}`: δxx→EXX, δzx→EZX |
//! | Asad Ullah 2013 | `εab` (`eps_ab`) | rotation about a while b moves | εyz→EBZ |
//! | Asad Ullah 2013 | `Szx` (`Sxz`) | squareness Z–X | EB0Z |
//! | Spaan 1995, VDI 2617 | `itj` | axis i translates in direction j | xtx→EXX, xty→EYX, ztx→EXZ |
//! | Spaan 1995, VDI 2617 | `irj` | axis i rotates about j | xry→EBX, zrz→ECZ |
//! | Spaan 1995, VDI 2617 | `xsy`, `xsz`, `ysz` | squareness | EC0Y, EB0Z, EA0Z |
//! | Graves 1997, Error File | `ax{Lin,Str,Ang}{e}{m}` | digits: 0 = X, 1 = Z, 2 = Y (vertical) | axLin00→EXX, axLin11→EZZ, axStr10→EZX, axStr01→EXZ, axAng20→EBX, axAng21→EBZ |
//! | Graves 1997 | `axSquXZ` (α), `axParZS` (β) | squareness X–Z, parallelism Z–spindle | EB0Z (on x, value −α; on z, value +β) |
//!
//! Only *names* are mapped here. Sign and frame conventions differ between the seeds (Graves states
//! the Z-slide errors as carriage motions in the base frame; retrocomp states every component as the
//! tool-relative-to-workpiece error, see `docs/model.md`), so a seed's numbers may need a sign change
//! that the loader cannot guess; the fixture tests show each mapping explicitly.

use std::fmt;

/// A machine axis letter. Index 0, 1, 2 = x, y, z in every `[f64; 3]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Axis {
    X = 0,
    Y = 1,
    Z = 2,
}

impl Axis {
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

    pub fn index(self) -> usize {
        self as usize
    }

    pub fn from_letter(c: char) -> Option<Axis> {
        match c.to_ascii_lowercase() {
            'x' => Some(Axis::X),
            'y' => Some(Axis::Y),
            'z' => Some(Axis::Z),
            _ => None,
        }
    }

    /// The axis named exactly `x`, `y` or `z` (the spelling of field files, status and sinks).
    pub fn from_name(name: &str) -> Option<Axis> {
        match name {
            "x" => Some(Axis::X),
            "y" => Some(Axis::Y),
            "z" => Some(Axis::Z),
            _ => None,
        }
    }

    /// `"x"`, `"y"`, `"z"`: the name as field files, status JSON, metrics and logs spell it.
    pub fn name(self) -> &'static str {
        ["x", "y", "z"][self.index()]
    }

    pub fn lower(self) -> char {
        ['x', 'y', 'z'][self.index()]
    }

    pub fn upper(self) -> char {
        ['X', 'Y', 'Z'][self.index()]
    }

    /// ISO rotation letter about this axis: A about X, B about Y, C about Z.
    pub fn rotation_letter(self) -> char {
        ['A', 'B', 'C'][self.index()]
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl PartialEq<str> for Axis {
    fn eq(&self, other: &str) -> bool {
        self.name() == other
    }
}

impl PartialEq<&str> for Axis {
    fn eq(&self, other: &&str) -> bool {
        self.name() == *other
    }
}

/// Whether a component is a translation (µm) or a rotation (µrad).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Motion {
    /// Translation along the axis given.
    Translation(Axis),
    /// Rotation about the axis given (right-hand rule).
    Rotation(Axis),
}

/// One of the 18 per-axis error motions: which axis moves, and which error it makes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ComponentId {
    /// The axis whose position the error depends on (the K in EXK).
    pub axis: Axis,
    pub motion: Motion,
}

impl ComponentId {
    pub fn is_rotation(self) -> bool {
        matches!(self.motion, Motion::Rotation(_))
    }

    /// Slot 0..6 within the axis: 0..3 translations x, y, z; 3..6 rotations a, b, c.
    pub fn slot(self) -> usize {
        match self.motion {
            Motion::Translation(a) => a.index(),
            Motion::Rotation(a) => 3 + a.index(),
        }
    }

    /// The ISO 230-1 name, e.g. `EXX`, `EBZ`.
    pub fn iso_name(self) -> String {
        let e = match self.motion {
            Motion::Translation(a) => a.upper(),
            Motion::Rotation(a) => a.rotation_letter(),
        };
        format!("E{e}{}", self.axis.upper())
    }
}

/// A squareness error: ISO name and the pair of axes it relates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Squareness {
    /// X–Y, rotation about Z. Positive opens the angle between +X and +Y (ISO: Y rotated about +Z).
    EC0Y,
    /// X–Z, rotation about Y. Positive closes the angle between +X and +Z (ISO: Z rotated about +Y).
    EB0Z,
    /// Y–Z, rotation about X. Positive opens the angle between +Y and +Z (ISO: Z rotated about +X).
    EA0Z,
}

impl Squareness {
    pub fn iso_name(self) -> &'static str {
        match self {
            Squareness::EC0Y => "EC0Y",
            Squareness::EB0Z => "EB0Z",
            Squareness::EA0Z => "EA0Z",
        }
    }

    /// (reference axis, axis rotated by ISO's definition, rotation axis).
    pub fn axes(self) -> (Axis, Axis, Axis) {
        match self {
            Squareness::EC0Y => (Axis::X, Axis::Y, Axis::Z),
            Squareness::EB0Z => (Axis::X, Axis::Z, Axis::Y),
            Squareness::EA0Z => (Axis::Y, Axis::Z, Axis::X),
        }
    }
}

/// Parse a component name: ISO 230-1 or one of the seeds' aliases listed in the module table.
pub fn parse_component(name: &str) -> Option<ComponentId> {
    let n = name.trim();
    if let Some(id) = parse_iso(n) {
        return Some(id);
    }
    let lower = n.to_lowercase();
    // δab / dab / delta_ab: translation along a while b moves.
    for prefix in ["δ", "delta_", "d"] {
        if let Some(rest) = lower.strip_prefix(prefix)
            && let Some((a, b)) = two_axes(rest)
        {
            return Some(ComponentId {
                axis: b,
                motion: Motion::Translation(a),
            });
        }
    }
    // εab / eps_ab: rotation about a while b moves.
    for prefix in ["ε", "eps_"] {
        if let Some(rest) = lower.strip_prefix(prefix)
            && let Some((a, b)) = two_axes(rest)
        {
            return Some(ComponentId {
                axis: b,
                motion: Motion::Rotation(a),
            });
        }
    }
    // VDI 2617: itj / irj.
    let c: Vec<char> = lower.chars().collect();
    if c.len() == 3
        && let (Some(i), Some(j)) = (Axis::from_letter(c[0]), Axis::from_letter(c[2]))
    {
        match c[1] {
            't' => {
                return Some(ComponentId {
                    axis: i,
                    motion: Motion::Translation(j),
                });
            }
            'r' => {
                return Some(ComponentId {
                    axis: i,
                    motion: Motion::Rotation(j),
                });
            }
            _ => {}
        }
    }
    // Graves Error File: ax{Lin,Str,Ang}{err}{motion}, digits 0 = X, 1 = Z, 2 = Y.
    let graves_axis = |d: char| match d {
        '0' => Some(Axis::X),
        '1' => Some(Axis::Z),
        '2' => Some(Axis::Y),
        _ => None,
    };
    if let Some(rest) = n.strip_prefix("ax") {
        let kind = rest.get(..3)?;
        let digits: Vec<char> = rest.get(3..)?.chars().collect();
        if digits.len() == 2 {
            let (e, m) = (graves_axis(digits[0])?, graves_axis(digits[1])?);
            return match kind {
                "Lin" if e == m => Some(ComponentId {
                    axis: m,
                    motion: Motion::Translation(e),
                }),
                "Str" if e != m => Some(ComponentId {
                    axis: m,
                    motion: Motion::Translation(e),
                }),
                "Ang" => Some(ComponentId {
                    axis: m,
                    motion: Motion::Rotation(e),
                }),
                _ => None,
            };
        }
    }
    None
}

fn parse_iso(n: &str) -> Option<ComponentId> {
    let c: Vec<char> = n.chars().collect();
    if c.len() != 3 || c[0] != 'E' {
        return None;
    }
    let axis = match c[2] {
        'X' => Axis::X,
        'Y' => Axis::Y,
        'Z' => Axis::Z,
        _ => return None,
    };
    let motion = match c[1] {
        'X' => Motion::Translation(Axis::X),
        'Y' => Motion::Translation(Axis::Y),
        'Z' => Motion::Translation(Axis::Z),
        'A' => Motion::Rotation(Axis::X),
        'B' => Motion::Rotation(Axis::Y),
        'C' => Motion::Rotation(Axis::Z),
        _ => return None,
    };
    Some(ComponentId { axis, motion })
}

fn two_axes(s: &str) -> Option<(Axis, Axis)> {
    let c: Vec<char> = s.chars().collect();
    if c.len() != 2 {
        return None;
    }
    Some((Axis::from_letter(c[0])?, Axis::from_letter(c[1])?))
}

/// Parse a squareness name: ISO or a seed alias (Szx/Sxz, VDI xsy/xsz/ysz, Graves axSquXZ/axParZS,
/// axSqu01/02/12).
pub(crate) fn parse_squareness(name: &str) -> Option<Squareness> {
    match name.trim() {
        "EC0Y" | "xsy" | "Sxy" | "Syx" | "axSqu02" => Some(Squareness::EC0Y),
        "EB0Z" | "xsz" | "Sxz" | "Szx" | "axSquXZ" | "axParZS" | "axSqu01" => {
            Some(Squareness::EB0Z)
        }
        "EA0Z" | "ysz" | "Syz" | "Szy" | "axSqu12" => Some(Squareness::EA0Z),
        _ => None,
    }
}

/// The axes' lower-case names (`x`, `y`, `z`), for messages that list what a key may name.
pub(super) fn lower_names(axes: &[Axis]) -> Vec<String> {
    axes.iter().map(|a| a.lower().to_string()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn iso(n: &str) -> String {
        parse_component(n)
            .map(|c| c.iso_name())
            .unwrap_or_else(|| format!("?{n}"))
    }

    #[test]
    fn iso_names_round_trip_all_18() {
        for axis in Axis::ALL {
            for slot in 0..6 {
                let a = Axis::ALL[slot % 3];
                let motion = if slot < 3 {
                    Motion::Translation(a)
                } else {
                    Motion::Rotation(a)
                };
                let id = ComponentId { axis, motion };
                assert_eq!(id.slot(), slot);
                assert_eq!(parse_component(&id.iso_name()), Some(id));
            }
        }
    }

    #[test]
    fn seed_aliases_map_to_iso() {
        // Asad Ullah 2013 §1.2 (Table 6.1/6.2 headings).
        assert_eq!(iso("δxx"), "EXX");
        assert_eq!(iso("δzx"), "EZX");
        assert_eq!(iso("δxz"), "EXZ");
        assert_eq!(iso("εyz"), "EBZ");
        // Spaan 1995 Ch2, VDI 2617.
        assert_eq!(iso("xtx"), "EXX");
        assert_eq!(iso("ztx"), "EXZ");
        assert_eq!(iso("xry"), "EBX");
        assert_eq!(iso("zrz"), "ECZ");
        // Graves 1997 Error File.
        assert_eq!(iso("axLin00"), "EXX");
        assert_eq!(iso("axLin11"), "EZZ");
        assert_eq!(iso("axStr10"), "EZX");
        assert_eq!(iso("axStr01"), "EXZ");
        assert_eq!(iso("axAng20"), "EBX");
        assert_eq!(iso("axAng21"), "EBZ");
        assert_eq!(parse_component("axLin01"), None, "Lin needs equal digits");
        assert_eq!(parse_component("EQX"), None);
        assert_eq!(parse_squareness("Szx"), Some(Squareness::EB0Z));
        assert_eq!(parse_squareness("xsy"), Some(Squareness::EC0Y));
        assert_eq!(parse_squareness("ysz"), Some(Squareness::EA0Z));
        assert_eq!(parse_squareness("EB0Y"), None);
    }
}
