//! The one vocabulary of Modbus register words, shared by every register map in the workspace (the
//! gateway's Modbus sources `regmap`, the origin-shift sinks `origin_shift::map`, hil-sim's PLC):
//! the data type of a value ([`DataType`]), the order of the two words of a 32-bit value
//! ([`WordOrder`]), and the one 32-bit ↔ two-word split ([`split_u32`], [`join_u32`]).
//!
//! Bytes inside a word are always big-endian, as the protocol defines; only the order of the two words
//! varies between devices. TOML spelling: `word_order = "high_first"` (ABCD, Modbus big-endian, the
//! default) or `"low_first"` (CDAB, word-swapped, common on PLCs). The older spellings `abcd`/`cdab`
//! and `hi_lo`/`lo_hi` are still read, and [`deprecated_spellings`] finds them (file line) so each
//! loader can warn once per use.

use toml::de::{DeTable, DeValue};

/// Type of the value held in one register (16-bit types) or two (32-bit types).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DataType {
    Int16,
    Uint16,
    Int32,
    Uint32,
    Float32,
}

impl DataType {
    /// Registers the type spans.
    pub fn words(self) -> u16 {
        match self {
            DataType::Int16 | DataType::Uint16 => 1,
            DataType::Int32 | DataType::Uint32 | DataType::Float32 => 2,
        }
    }
}

/// Order of the two 16-bit words of a 32-bit value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
pub enum WordOrder {
    /// ABCD: high word at the lower address (Modbus big-endian).
    #[default]
    #[serde(rename = "high_first", alias = "abcd", alias = "hi_lo")]
    HighFirst,
    /// CDAB: low word at the lower address (word-swapped).
    #[serde(rename = "low_first", alias = "cdab", alias = "lo_hi")]
    LowFirst,
}

/// Old TOML spellings of [`WordOrder`] and the one to write instead.
const DEPRECATED_WORD_ORDERS: [(&str, &str); 4] = [
    ("abcd", "high_first"),
    ("hi_lo", "high_first"),
    ("cdab", "low_first"),
    ("lo_hi", "low_first"),
];

/// The two words of `v`, in address order.
pub fn split_u32(v: u32, order: WordOrder) -> [u16; 2] {
    let [h1, h0, l1, l0] = v.to_be_bytes();
    let (high, low) = (u16::from_be_bytes([h1, h0]), u16::from_be_bytes([l1, l0]));
    match order {
        WordOrder::HighFirst => [high, low],
        WordOrder::LowFirst => [low, high],
    }
}

/// The 32-bit value of two words in address order (inverse of [`split_u32`]).
pub(crate) fn join_u32(words: [u16; 2], order: WordOrder) -> u32 {
    let (high, low) = match order {
        WordOrder::HighFirst => (words[0], words[1]),
        WordOrder::LowFirst => (words[1], words[0]),
    };
    (u32::from(high) << 16) | u32::from(low)
}

/// One use of an old spelling in a TOML text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Deprecated {
    /// 1-based line of the value.
    pub line: usize,
    /// Dotted key path (`sink.origin_shift.map.axis[0].word_order`).
    pub key: String,
    pub found: String,
    pub instead: &'static str,
}

impl Deprecated {
    /// `file:line: key `k`: word_order "cdab" is deprecated, write "low_first"`.
    pub(crate) fn message(&self, file: &str) -> String {
        format!(
            "{file}:{}: key `{}`: \"{}\" is a deprecated spelling, write \"{}\"",
            self.line, self.key, self.found, self.instead
        )
    }
}

/// Every `word_order` in `text` spelled the old way. A text that is not TOML yields nothing (its
/// loader reports the syntax error).
pub(crate) fn deprecated_spellings(text: &str) -> Vec<Deprecated> {
    let mut out = Vec::new();
    if let Ok(root) = DeTable::parse(text) {
        walk_table(text, root.get_ref(), "", &mut out);
    }
    // The parsed table is a map, not in file order.
    out.sort_by_key(|d| d.line);
    out
}

/// Every `word_order` in `text` spelled the old way, each logged as a WARN naming `file` and line;
/// returns the messages.
pub fn warn_deprecated_spellings(text: &str, file: &str) -> Vec<String> {
    deprecated_spellings(text)
        .iter()
        .map(|d| {
            let m = d.message(file);
            tracing::warn!("{m}");
            m
        })
        .collect()
}

fn walk_table(text: &str, t: &DeTable<'_>, path: &str, out: &mut Vec<Deprecated>) {
    for (k, v) in t {
        let key = if path.is_empty() {
            k.get_ref().to_string()
        } else {
            format!("{path}.{}", k.get_ref())
        };
        walk_value(text, v, &key, k.get_ref() == "word_order", out);
    }
}

fn walk_value(
    text: &str,
    v: &toml::Spanned<DeValue<'_>>,
    key: &str,
    is_word_order: bool,
    out: &mut Vec<Deprecated>,
) {
    match v.get_ref() {
        DeValue::Table(t) => walk_table(text, t, key, out),
        DeValue::Array(a) => {
            for (i, item) in a.iter().enumerate() {
                walk_value(text, item, &format!("{key}[{i}]"), false, out);
            }
        }
        DeValue::String(s) if is_word_order => {
            if let Some((found, instead)) = DEPRECATED_WORD_ORDERS.iter().find(|(o, _)| o == s) {
                out.push(Deprecated {
                    line: line_of(text, v.span().start),
                    key: key.to_string(),
                    found: (*found).to_string(),
                    instead,
                });
            }
        }
        _ => {}
    }
}

fn line_of(text: &str, byte: usize) -> usize {
    text.as_bytes()[..byte.min(text.len())]
        .iter()
        .filter(|&&c| c == b'\n')
        .count()
        + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_and_join_are_inverse_in_both_orders() {
        for v in [
            0u32,
            1,
            0xFFFF,
            0x1_0000,
            0x1234_5678,
            u32::MAX,
            (-25i32).cast_unsigned(),
        ] {
            for o in [WordOrder::HighFirst, WordOrder::LowFirst] {
                assert_eq!(join_u32(split_u32(v, o), o), v);
            }
        }
        assert_eq!(split_u32(0x0001_0002, WordOrder::HighFirst), [1, 2]);
        assert_eq!(split_u32(0x0001_0002, WordOrder::LowFirst), [2, 1]);
    }

    #[derive(serde::Deserialize, serde::Serialize)]
    struct W {
        word_order: WordOrder,
    }

    #[test]
    fn every_spelling_reads_and_the_new_one_is_written() {
        for (s, want) in [
            ("high_first", WordOrder::HighFirst),
            ("abcd", WordOrder::HighFirst),
            ("hi_lo", WordOrder::HighFirst),
            ("low_first", WordOrder::LowFirst),
            ("cdab", WordOrder::LowFirst),
            ("lo_hi", WordOrder::LowFirst),
        ] {
            let w: W = toml::from_str(&format!("word_order = \"{s}\"")).unwrap();
            assert_eq!(w.word_order, want, "{s}");
        }
        assert!(toml::from_str::<W>("word_order = \"badc\"").is_err());
        let w = W {
            word_order: WordOrder::LowFirst,
        };
        assert_eq!(
            toml::to_string(&w).unwrap().trim(),
            "word_order = \"low_first\""
        );
    }

    #[test]
    fn old_spellings_are_found_with_line_and_key() {
        let text = "word_order = \"high_first\"\n[a]\nword_order = \"cdab\"\n[[a.b]]\nx = 1\n\
                    word_order = \"hi_lo\"\n[[a.b]]\nword_order = \"low_first\"\nname = \"abcd\"\n";
        let d = deprecated_spellings(text);
        assert_eq!(d.len(), 2, "{d:?}");
        assert_eq!((d[0].line, d[0].key.as_str()), (3, "a.word_order"));
        assert_eq!(d[0].instead, "low_first");
        assert_eq!((d[1].line, d[1].key.as_str()), (6, "a.b[0].word_order"));
        assert_eq!(
            d[1].message("f.toml"),
            "f.toml:6: key `a.b[0].word_order`: \"hi_lo\" is a deprecated spelling, write \"high_first\""
        );
        assert!(deprecated_spellings("not [ toml").is_empty());
    }
}
