//! Maps TOML key paths to source positions and back.
//!
//! `toml` reports a span for syntax and type errors but not the key, and
//! validation (which runs on the deserialized model) knows the key but not
//! the span. This is a small, tolerant TOML *scanner* — strings, comments,
//! brackets, `=`, `,`, headers, dotted keys, inline tables, arrays, arrays
//! of tables — that records, for every key and array element, its path
//! (`spheres[2].center[1]`) and the byte ranges of its key and value. It
//! does not validate anything; on text `toml` rejected it simply records
//! what it can. It runs only when an error is being reported.

use std::collections::HashMap;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    LBracket,
    RBracket,
    LBrace,
    RBrace,
    Eq,
    Comma,
    Newline,
    Str(String),
    Bare(String),
}

fn tokenize(text: &str) -> Vec<(Tok, Range<usize>)> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let start = i;
        match b[i] {
            b' ' | b'\t' | b'\r' => i += 1,
            b'\n' => {
                i += 1;
                out.push((Tok::Newline, start..i));
            }
            b'#' => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b'[' | b']' | b'{' | b'}' | b'=' | b',' => {
                let t = match b[i] {
                    b'[' => Tok::LBracket,
                    b']' => Tok::RBracket,
                    b'{' => Tok::LBrace,
                    b'}' => Tok::RBrace,
                    b'=' => Tok::Eq,
                    _ => Tok::Comma,
                };
                i += 1;
                out.push((t, start..i));
            }
            q @ (b'"' | b'\'') => {
                let triple = b.get(i..i + 3) == Some(&[q, q, q][..]);
                let escapes = q == b'"';
                let mut s = Vec::new();
                if triple {
                    i += 3;
                    while i < b.len() && b.get(i..i + 3) != Some(&[q, q, q][..]) {
                        if escapes && b[i] == b'\\' && i + 1 < b.len() {
                            s.push(b[i + 1]);
                            i += 2;
                        } else {
                            s.push(b[i]);
                            i += 1;
                        }
                    }
                    i = (i + 3).min(b.len());
                    // Up to two extra quotes may close a multi-line string.
                    while i < b.len() && b[i] == q {
                        i += 1;
                    }
                } else {
                    i += 1;
                    while i < b.len() && b[i] != q && b[i] != b'\n' {
                        if escapes && b[i] == b'\\' && i + 1 < b.len() {
                            s.push(b[i + 1]);
                            i += 2;
                        } else {
                            s.push(b[i]);
                            i += 1;
                        }
                    }
                    if i < b.len() && b[i] == q {
                        i += 1;
                    }
                }
                out.push((Tok::Str(String::from_utf8_lossy(&s).into_owned()), start..i));
            }
            _ => {
                while i < b.len()
                    && !matches!(
                        b[i],
                        b' ' | b'\t'
                            | b'\r'
                            | b'\n'
                            | b'#'
                            | b'['
                            | b']'
                            | b'{'
                            | b'}'
                            | b'='
                            | b','
                            | b'"'
                            | b'\''
                    )
                {
                    i += 1;
                }
                out.push((Tok::Bare(text[start..i].to_owned()), start..i));
            }
        }
    }
    out
}

/// Append a key segment to a path string, quoting keys that are not bare.
pub(crate) fn push_key(path: &mut String, key: &str) {
    if !path.is_empty() {
        path.push('.');
    }
    let bare = !key.is_empty()
        && key
            .bytes()
            .all(|c| c.is_ascii_alphanumeric() || c == b'_' || c == b'-');
    if bare {
        path.push_str(key);
    } else {
        path.push('"');
        for c in key.chars() {
            if c == '"' || c == '\\' {
                path.push('\\');
            }
            path.push(c);
        }
        path.push('"');
    }
}

#[derive(Clone, Debug)]
struct Entry {
    path: String,
    key: Range<usize>,
    value: Range<usize>,
}

/// Index of key paths in one TOML text.
#[derive(Debug, Default)]
pub(crate) struct Locator {
    entries: Vec<Entry>,
}

const MAX_NESTING: usize = 64;

struct Parser<'a> {
    toks: &'a [(Tok, Range<usize>)],
    pos: usize,
    entries: Vec<Entry>,
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos).map(|t| &t.0)
    }

    fn span(&self) -> Range<usize> {
        self.toks
            .get(self.pos)
            .map_or(usize::MAX..usize::MAX, |t| t.1.clone())
    }

    fn end_of_prev(&self) -> usize {
        self.pos
            .checked_sub(1)
            .and_then(|p| self.toks.get(p))
            .map_or(0, |t| t.1.end)
    }

    fn skip_newlines(&mut self) {
        while self.peek() == Some(&Tok::Newline) {
            self.pos += 1;
        }
    }

    /// Key parts up to (not including) `=` or `]`.
    fn key_parts(&mut self) -> Vec<String> {
        let mut parts = Vec::new();
        while let Some(t) = self.peek() {
            match t {
                Tok::Bare(s) => {
                    parts.extend(s.split('.').filter(|p| !p.is_empty()).map(str::to_owned));
                }
                Tok::Str(s) => parts.push(s.clone()),
                _ => break,
            }
            self.pos += 1;
        }
        parts
    }

    fn value(&mut self, path: &str, key: Range<usize>, depth: usize) {
        let start = self.span().start;
        match self.peek() {
            Some(Tok::LBrace) if depth < MAX_NESTING => {
                self.pos += 1;
                loop {
                    self.skip_newlines();
                    match self.peek() {
                        None => break,
                        Some(Tok::RBrace) => {
                            self.pos += 1;
                            break;
                        }
                        Some(Tok::Comma) => self.pos += 1,
                        _ => {
                            let k0 = self.span().start;
                            let parts = self.key_parts();
                            let k1 = self.end_of_prev();
                            if self.peek() != Some(&Tok::Eq) {
                                self.pos += 1; // tolerate garbage
                                continue;
                            }
                            self.pos += 1;
                            let mut p = path.to_owned();
                            for part in &parts {
                                push_key(&mut p, part);
                            }
                            self.value(&p, k0..k1, depth + 1);
                        }
                    }
                }
            }
            Some(Tok::LBracket) if depth < MAX_NESTING => {
                self.pos += 1;
                let mut index = 0usize;
                loop {
                    self.skip_newlines();
                    match self.peek() {
                        None => break,
                        Some(Tok::RBracket) => {
                            self.pos += 1;
                            break;
                        }
                        Some(Tok::Comma) => self.pos += 1,
                        Some(Tok::Eq | Tok::RBrace) => self.pos += 1,
                        _ => {
                            let p = format!("{path}[{index}]");
                            let s = self.span();
                            self.value(&p, s.start..s.start, depth + 1);
                            index += 1;
                        }
                    }
                }
            }
            _ => {
                // A scalar: one or more adjacent bare/string tokens (a
                // date-time may contain a space).
                let mut any = false;
                while let Some(Tok::Bare(_) | Tok::Str(_)) = self.peek() {
                    self.pos += 1;
                    any = true;
                }
                if !any && self.peek().is_some() && self.peek() != Some(&Tok::Newline) {
                    self.pos += 1;
                }
            }
        }
        let end = self.end_of_prev();
        self.entries.push(Entry {
            path: path.to_owned(),
            key,
            value: start.min(end)..end,
        });
    }

    fn document(&mut self) {
        let mut table = String::new();
        let mut aot: HashMap<String, usize> = HashMap::new();
        let mut open_header: Option<usize> = None;
        loop {
            self.skip_newlines();
            let Some(tok) = self.peek() else { break };
            if *tok == Tok::LBracket {
                let h0 = self.span().start;
                self.pos += 1;
                let is_aot = self.peek() == Some(&Tok::LBracket) && self.span().start == h0 + 1;
                if is_aot {
                    self.pos += 1;
                }
                let parts = self.key_parts();
                while let Some(Tok::RBracket) = self.peek() {
                    self.pos += 1;
                }
                let h1 = self.end_of_prev();
                let mut path = String::new();
                let n = parts.len();
                for (k, part) in parts.iter().enumerate() {
                    push_key(&mut path, part);
                    if k + 1 == n && is_aot {
                        let c = aot.entry(path.clone()).or_insert(0);
                        *c += 1;
                        path = format!("{path}[{}]", *c - 1);
                    } else if let Some(c) = aot.get(&path) {
                        path = format!("{path}[{}]", c.saturating_sub(1));
                    }
                }
                if let Some(e) = open_header.and_then(|h| self.entries.get_mut(h)) {
                    e.value.end = h0;
                }
                open_header = Some(self.entries.len());
                self.entries.push(Entry {
                    path: path.clone(),
                    key: h0..h1,
                    value: h0..usize::MAX,
                });
                table = path;
            } else {
                let k0 = self.span().start;
                let parts = self.key_parts();
                let k1 = self.end_of_prev();
                if self.peek() == Some(&Tok::Eq) && !parts.is_empty() {
                    self.pos += 1;
                    let mut p = table.clone();
                    for part in &parts {
                        push_key(&mut p, part);
                    }
                    self.value(&p, k0..k1, 0);
                }
            }
            // Resynchronise at the end of the line.
            while let Some(t) = self.peek() {
                if *t == Tok::Newline {
                    break;
                }
                self.pos += 1;
            }
        }
    }
}

impl Locator {
    /// Index `text`.
    pub(crate) fn new(text: &str) -> Self {
        let toks = tokenize(text);
        let mut p = Parser {
            toks: &toks,
            pos: 0,
            entries: Vec::new(),
        };
        p.document();
        for e in &mut p.entries {
            e.value.end = e.value.end.min(text.len());
        }
        Locator { entries: p.entries }
    }

    /// Byte offset of the key `path`, or of its nearest recorded ancestor
    /// (`spheres[2].radius` falls back to `spheres[2]`), with the path that
    /// was found.
    pub(crate) fn find(&self, path: &str) -> Option<(usize, &str)> {
        let mut p = path;
        loop {
            if let Some(e) = self.entries.iter().find(|e| e.path == p) {
                return Some((e.key.start, &e.path));
            }
            // Strip the last `.key` or `[i]` segment.
            let cut = if p.ends_with(']') {
                p.rfind('[')
            } else {
                p.rfind(['.', '['])
            };
            match cut {
                Some(c) if c > 0 => p = &p[..c],
                _ => return None,
            }
        }
    }

    /// The innermost key path whose key or value contains byte `offset`.
    pub(crate) fn path_at(&self, offset: usize) -> Option<&str> {
        self.entries
            .iter()
            .filter(|e| {
                e.key.contains(&offset) || e.value.contains(&offset) || e.value.start == offset
            })
            .min_by_key(|e| {
                if e.key.contains(&offset) {
                    0
                } else {
                    e.value.end.saturating_sub(e.value.start).saturating_add(1)
                }
            })
            .map(|e| e.path.as_str())
    }
}

/// 1-based (line, column) of a byte offset; the column counts characters.
pub(crate) fn line_col(text: &str, offset: usize) -> (u32, u32) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.bytes().filter(|&b| b == b'\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |p| p + 1);
    let col = text[line_start..offset].chars().count() + 1;
    (
        u32::try_from(line).unwrap_or(u32::MAX),
        u32::try_from(col).unwrap_or(u32::MAX),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_and_positions() {
        let text = "ambient = [0.1, 0.1, 0.1]\n\
                    [settings]\nwidth = 3 # c\nao.radius = 2\n\
                    [[spheres]]\ncenter = [1, 2, 3]\nradius = 2\n\
                    [[spheres]]\nradius = \"x\"\n\
                    [materials.\"my mat\"]\nior = 1.5\n\
                    [[meshes]]\npositions = [\n  [0, 0, 0],\n  [1, 0, 0],\n]\n\
                    generate = { kind = 'grid', nx = 2 }\n";
        let loc = Locator::new(text);
        let line_of = |p: &str| loc.find(p).map(|(o, _)| line_col(text, o).0 as usize);
        assert_eq!(line_of("ambient"), Some(1));
        assert_eq!(line_of("settings.width"), Some(3));
        assert_eq!(line_of("settings.ao.radius"), Some(4));
        assert_eq!(line_of("spheres[0].radius"), Some(7));
        assert_eq!(line_of("spheres[1].radius"), Some(9));
        assert_eq!(line_of("spheres[1].center"), Some(8)); // falls back to the table
        assert_eq!(line_of("materials.\"my mat\".ior"), Some(11));
        assert_eq!(line_of("meshes[0].positions[1]"), Some(15));
        assert_eq!(line_of("meshes[0].generate.nx"), Some(17));
        let off = text.find("\"x\"").unwrap();
        assert_eq!(loc.path_at(off), Some("spheres[1].radius"));
        let off = text.find("nx").unwrap();
        assert_eq!(loc.path_at(off), Some("meshes[0].generate.nx"));
    }

    #[test]
    fn survives_garbage() {
        for text in [
            "[[[",
            "a = [[[[",
            "= = =",
            "a.b.c",
            "\"unterminated",
            "'''",
            "x = {a = [1, {b",
        ] {
            let loc = Locator::new(text);
            let _ = loc.path_at(1);
            let _ = loc.find("a.b");
        }
        let deep = "a = ".to_owned() + &"[".repeat(100_000);
        let _ = Locator::new(&deep).path_at(5);
    }
}
