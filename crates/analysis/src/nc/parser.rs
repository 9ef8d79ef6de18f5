//! G-code block parser (ISO 6983 / Fanuc dialect): words `<letter><number>`, `( … )` comments,
//! `%` tape marks, and `;` as end of block (Fanuc EOB; set `semicolon_is_eob = false` for
//! LinuxCNC, where `;` starts a comment). Letters are case-insensitive (upper-cased).
//! Bad words are reported with line and column; nothing is skipped. O-words, `#` parameters and
//! `[ … ]` expressions are refused as not supported (the rewriter works on plain numbered words).

use crate::import_error::{ErrorSink, ImportErrors};

#[derive(Debug, Clone, PartialEq)]
pub struct Word {
    pub letter: char,
    pub value: f64,
    /// The number as written (kept so untouched words are re-emitted byte for byte).
    pub text: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// 1-based source line.
    pub line: u64,
    pub words: Vec<Word>,
    /// The block's source text (without EOB), for verbatim pass-through.
    pub source: String,
}

impl Block {
    pub fn get(&self, letter: char) -> Option<&Word> {
        self.words.iter().find(|w| w.letter == letter)
    }

    /// G codes in the block (G4, G01 → 1, …); fractional codes (G64.1) keep their fraction.
    pub fn g_codes(&self) -> impl Iterator<Item = f64> + '_ {
        self.words
            .iter()
            .filter(|w| w.letter == 'G')
            .map(|w| w.value)
    }

    pub fn has_g(&self, code: f64) -> bool {
        self.g_codes().any(|g| (g - code).abs() < 1e-9)
    }
}

/// Parses a program into blocks. Empty blocks are dropped; tape marks (`%`) and comment-only
/// blocks are kept with no words so they are re-emitted. Every bad word is reported.
pub fn parse_program(
    file: &str,
    text: &str,
    semicolon_is_eob: bool,
) -> Result<Vec<Block>, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut blocks = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        parse_line_into(&mut sink, i as u64 + 1, raw, semicolon_is_eob, &mut blocks);
    }
    sink.finish(blocks)
}

/// Parses one source line (for streaming readers): its blocks, or the line's errors.
pub fn parse_line(
    file: &str,
    line: u64,
    raw: &str,
    semicolon_is_eob: bool,
) -> Result<Vec<Block>, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut blocks = Vec::new();
    parse_line_into(&mut sink, line, raw, semicolon_is_eob, &mut blocks);
    sink.finish(blocks)
}

fn parse_line_into(
    sink: &mut ErrorSink,
    line: u64,
    raw: &str,
    semicolon_is_eob: bool,
    blocks: &mut Vec<Block>,
) {
    let first = blocks.len();
    for piece in split_blocks(raw, semicolon_is_eob) {
        let source = piece.trim();
        if source.is_empty() {
            continue;
        }
        if source == "%" {
            blocks.push(Block {
                line,
                words: Vec::new(),
                source: source.to_string(),
            });
            continue;
        }
        if let Some(words) = parse_words(sink, line, source) {
            blocks.push(Block {
                line,
                words,
                source: source.to_string(),
            });
        }
    }
    // LinuxCNC's `; comment` runs to the end of the line: it stays with the line's block (or is a
    // comment-only block of its own), so the rewrite keeps it.
    if let Some(tail) = semicolon_comment(raw, semicolon_is_eob) {
        match blocks.get_mut(first..).and_then(|b| b.last_mut()) {
            Some(b) => {
                b.source.push(' ');
                b.source.push_str(tail);
            }
            None => blocks.push(Block {
                line,
                words: Vec::new(),
                source: tail.to_string(),
            }),
        }
    }
}

/// The `; …` comment of a LinuxCNC line (outside `( … )`), if any.
fn semicolon_comment(raw: &str, semicolon_is_eob: bool) -> Option<&str> {
    if semicolon_is_eob {
        return None;
    }
    let pieces = split_blocks(raw, false);
    let before = pieces.first()?.len();
    (before < raw.len()).then(|| raw[before..].trim_end())
}

/// The comments of a block's source (`( … )` and a LinuxCNC `; …` tail), space-separated, for
/// blocks whose words are written anew: a `(MSG, …)` or `(DEBUG, …)` stays with its block.
pub fn comments(source: &str) -> String {
    let mut out = String::new();
    let mut depth_start: Option<usize> = None;
    for (i, c) in source.char_indices() {
        match c {
            '(' if depth_start.is_none() => depth_start = Some(i),
            ')' => {
                if let Some(s) = depth_start.take() {
                    out.push_str(&source[s..=i]);
                    out.push(' ');
                }
            }
            ';' if depth_start.is_none() => {
                out.push_str(&source[i..]);
                break;
            }
            _ => {}
        }
    }
    out.trim_end().to_string()
}

/// The one lexical rule for `;`: inside a `( … )` comment it is text; outside, it ends the block
/// (Fanuc/ISO EOB) or starts a comment running to the end of the line (LinuxCNC). Comments do
/// not nest (ISO 6983, LinuxCNC): the first `)` closes.
pub fn split_blocks(raw: &str, semicolon_is_eob: bool) -> Vec<&str> {
    let mut out = Vec::new();
    let mut in_comment = false;
    let mut start = 0;
    for (i, c) in raw.char_indices() {
        match c {
            '(' => in_comment = true,
            ')' => in_comment = false,
            ';' if !in_comment => {
                out.push(&raw[start..i]);
                if !semicolon_is_eob {
                    return out;
                }
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&raw[start..]);
    out
}

/// The first `#` parameter or `[ … ]` expression outside comments, refused before any word: the
/// rewriter works on numbers only.
fn refuse_parameters(sink: &mut ErrorSink, line: u64, chars: &[char]) -> bool {
    let mut in_comment = false;
    for (i, &c) in chars.iter().enumerate() {
        let what = match c {
            '(' => {
                in_comment = true;
                continue;
            }
            ')' => {
                in_comment = false;
                continue;
            }
            '#' if !in_comment => {
                "`#` parameters (variables) are not supported by the rewriter: expand them to numbers first"
            }
            '[' if !in_comment => {
                "`[ … ]` expressions are not supported by the rewriter: expand them to numbers first"
            }
            _ => continue,
        };
        sink.push(line, Some(&format!("char {}", i + 1)), what);
        return true;
    }
    false
}

fn parse_words(sink: &mut ErrorSink, line: u64, src: &str) -> Option<Vec<Word>> {
    let chars: Vec<char> = src.chars().collect();
    if refuse_parameters(sink, line, &chars) {
        return None;
    }
    let mut words = Vec::new();
    let mut ok = true;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
        } else if c == '(' {
            match chars[i..].iter().position(|&c| c == ')') {
                Some(end) => i += end + 1,
                None => {
                    sink.push(
                        line,
                        Some(&format!("char {}", i + 1)),
                        "comment `(` is not closed",
                    );
                    return None;
                }
            }
        } else if c.eq_ignore_ascii_case(&'o') {
            sink.push(
                line,
                Some(&format!("char {}", i + 1)),
                "O-words (subprograms, program numbers, o-word control flow) are not supported by the rewriter: expand subprograms inline and remove the O-words first",
            );
            return None;
        } else if c.is_ascii_alphabetic() {
            let letter = c.to_ascii_uppercase();
            let mut j = i + 1;
            while j < chars.len() && chars[j] == ' ' {
                j += 1;
            }
            let num_start = j;
            while j < chars.len()
                && (chars[j].is_ascii_digit() || matches!(chars[j], '+' | '-' | '.'))
            {
                j += 1;
            }
            let text: String = chars[num_start..j].iter().collect();
            match text.parse::<f64>() {
                Ok(value) if value.is_finite() => words.push(Word {
                    letter,
                    value,
                    text,
                }),
                _ => {
                    sink.push(
                        line,
                        Some(&format!("char {}", i + 1)),
                        format!("word `{letter}` needs a number, found `{text}`"),
                    );
                    ok = false;
                }
            }
            i = j.max(i + 1);
        } else {
            sink.push(
                line,
                Some(&format!("char {}", i + 1)),
                format!("unexpected character `{c}`"),
            );
            ok = false;
            i += 1;
        }
    }
    ok.then_some(words)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_fanuc_blocks_with_eob_comments_and_lower_case() {
        let b = parse_program(
            "p.nc",
            "G01 X0 z-1.5 F1000; G04 X5 (dwell; 5 s)\n%\nM30;",
            true,
        )
        .unwrap();
        assert_eq!(b.len(), 4);
        assert_eq!(b[0].get('Z').unwrap().value, -1.5);
        assert!(b[0].has_g(1.0));
        assert_eq!(b[1].source, "G04 X5 (dwell; 5 s)");
        assert_eq!((b[2].source.as_str(), b[2].words.len()), ("%", 0));
        assert_eq!(b[3].line, 3);
    }

    #[test]
    fn semicolon_inside_a_comment_is_text_in_both_dialects() {
        // LinuxCNC: `(a; b)` is a comment, `; rest` a comment to the end of the line.
        let b = parse_program("c.ngc", "G1 X1 (a; b) Y2 ; tail (x\nG0 Z3", false).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0].get('Y').unwrap().value, 2.0);
        assert_eq!(b[0].source, "G1 X1 (a; b) Y2 ; tail (x");
        assert_eq!(comments(&b[0].source), "(a; b) ; tail (x");
        let b = parse_program("c.nc", "G1 X1 (a; b) Y2; Z4", true).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[1].get('Z').unwrap().value, 4.0);
    }

    #[test]
    fn typo_word_is_reported_with_position() {
        // Asad Ullah's compensated listing has `XX-0.0016` (digest §3.4).
        let e = parse_program("t.nc", "G04 X5\nXX-0.0016 Z-0.0007\n", true).unwrap_err();
        assert_eq!(e.0.len(), 1);
        assert_eq!(
            e.0[0].to_string(),
            "t.nc:2: column `char 1`: word `X` needs a number, found ``"
        );
    }
}
