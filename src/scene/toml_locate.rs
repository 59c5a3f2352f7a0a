//! Maps TOML key paths to source positions and back.
//!
//! `toml` reports a span for syntax and type errors but not the key, and
//! validation (which runs on the deserialized model) knows the key but not
//! the span. `toml_edit` parses the text again keeping every key's and
//! value's span; this walks that tree once and records, for every key and
//! array element, its path (`spheres[2].center[1]`) and byte ranges. It
//! runs only when an error is being reported; text that does not parse
//! gives an empty index (the error then has a line but no key).

use std::ops::Range;

use toml_edit::{ImDocument, Item, Key, Table, Value};

/// Append a key segment to a path, quoted as TOML would be if not bare.
pub(crate) fn push_key(path: &mut String, key: &str) {
    if !path.is_empty() {
        path.push('.');
    }
    path.push_str(&Key::new(key).display_repr());
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

impl Locator {
    /// Index `text` (empty if it is not valid TOML).
    pub(crate) fn new(text: &str) -> Self {
        let mut loc = Locator::default();
        if let Ok(doc) = ImDocument::parse(text) {
            loc.table(doc.as_table(), "");
        }
        loc
    }

    fn push(&mut self, path: &str, key: Option<Range<usize>>, value: Option<Range<usize>>) {
        let (key, value) = match (key, value) {
            (Some(k), Some(v)) => (k, v),
            (Some(k), None) => (k.clone(), k),
            (None, Some(v)) => (v.start..v.start, v),
            (None, None) => return, // an implicit table: not written anywhere
        };
        self.entries.push(Entry {
            path: path.to_owned(),
            key,
            value,
        });
    }

    fn table(&mut self, t: &Table, path: &str) {
        for (name, item) in t.iter() {
            let mut p = path.to_owned();
            push_key(&mut p, name);
            let key = t.key(name).and_then(Key::span);
            match item {
                Item::None => {}
                Item::Value(v) => {
                    self.push(&p, key, v.span());
                    self.value(v, &p);
                }
                // A `[header]` table's span runs from the header to its last
                // value; dotted and implicit tables have none.
                Item::Table(sub) => {
                    self.push(&p, sub.span().map(|s| s.start..s.start), sub.span());
                    self.table(sub, &p);
                }
                Item::ArrayOfTables(a) => {
                    for (i, sub) in a.iter().enumerate() {
                        let p = format!("{p}[{i}]");
                        self.push(&p, None, sub.span());
                        self.table(sub, &p);
                    }
                }
            }
        }
    }

    fn value(&mut self, v: &Value, path: &str) {
        match v {
            Value::Array(a) => {
                for (i, e) in a.iter().enumerate() {
                    let p = format!("{path}[{i}]");
                    self.push(&p, None, e.span());
                    self.value(e, &p);
                }
            }
            Value::InlineTable(t) => {
                for (name, e) in t.iter() {
                    let mut p = path.to_owned();
                    push_key(&mut p, name);
                    self.push(&p, t.key(name).and_then(Key::span), e.span());
                    self.value(e, &p);
                }
            }
            _ => {}
        }
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
    fn invalid_toml_gives_an_empty_index() {
        for text in [
            "[[[",
            "a = [[[[",
            "= = =",
            "\"unterminated",
            "x = {a = [1, {b",
        ] {
            let loc = Locator::new(text);
            assert_eq!(loc.path_at(1), None);
            assert_eq!(loc.find("a.b"), None);
        }
    }
}
