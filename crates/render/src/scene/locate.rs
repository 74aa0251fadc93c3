//! Maps a key path (`objects[3].radius`) back to a line and column of the source text, so that
//! errors found after parsing (a NaN radius, a missing material) point where the user must look.

use std::ops::Range;

use super::{KeyPath, Seg};

// JSON's brackets as bytes, named: the scanner below matches them by value.
/// Opens an object.
const OPEN_OBJECT: u8 = 0x7b;
/// Closes an object.
const CLOSE_OBJECT: u8 = 0x7d;
/// Opens an array.
const OPEN_ARRAY: u8 = 0x5b;
/// Closes an array.
const CLOSE_ARRAY: u8 = 0x5d;

/// 1-based line and column (in characters) of byte `offset`.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..text.floor_char_boundary(offset)];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// Span of the deepest existing prefix of `path` in a TOML document.
pub fn toml_span(text: &str, path: &KeyPath) -> Option<Range<usize>> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut best = None;
    walk_toml(TomlNode::Item(doc.as_item()), &path.0, &mut best);
    best
}

#[derive(Clone, Copy)]
enum TomlNode<'a> {
    Item(&'a toml_edit::Item),
    Value(&'a toml_edit::Value),
    Table(&'a toml_edit::Table),
}

fn walk_toml(node: TomlNode<'_>, segs: &[Seg], best: &mut Option<Range<usize>>) {
    use toml_edit::{Item, Value};
    let Some((seg, rest)) = segs.split_first() else {
        return;
    };
    match seg {
        // A place inside another file: the key that names the file is as far as this text goes.
        Seg::File(_) => {}
        Seg::Key(k) => {
            let table: Option<&dyn toml_edit::TableLike> = match node {
                TomlNode::Item(i) => i.as_table_like(),
                TomlNode::Value(v) => v.as_inline_table().map(|t| t as &dyn toml_edit::TableLike),
                TomlNode::Table(t) => Some(t),
            };
            if let Some((key, item)) = table.and_then(|t| t.get_key_value(k)) {
                if let Some(s) = item.span().or_else(|| key.span()) {
                    *best = Some(s);
                }
                walk_toml(TomlNode::Item(item), rest, best);
            }
        }
        Seg::Index(i) => {
            let array = match node {
                TomlNode::Item(Item::ArrayOfTables(a)) => {
                    if let Some(t) = a.get(*i) {
                        if let Some(s) = t.span() {
                            *best = Some(s);
                        }
                        walk_toml(TomlNode::Table(t), rest, best);
                    }
                    return;
                }
                TomlNode::Item(Item::Value(Value::Array(a))) | TomlNode::Value(Value::Array(a)) => {
                    a
                }
                _ => return,
            };
            if let Some(v) = array.get(*i) {
                if let Some(s) = v.span() {
                    *best = Some(s);
                }
                walk_toml(TomlNode::Value(v), rest, best);
            }
        }
    }
}

/// Span of the deepest existing prefix of `path` in a JSON document, found by a small
/// scanner (serde_json keeps no spans once a value is parsed).
pub fn json_span(text: &str, path: &KeyPath) -> Option<Range<usize>> {
    let b = text.as_bytes();
    let mut pos = skip_ws(b, 0);
    let mut best = Some(pos..pos);
    for seg in &path.0 {
        match (seg, b.get(pos)) {
            (Seg::Key(k), Some(&OPEN_OBJECT)) => {
                pos = skip_ws(b, pos + 1);
                let mut found = false;
                while b.get(pos) == Some(&b'"') {
                    let key_end = skip_string(b, pos)?;
                    let key: String = serde_json::from_slice(&b[pos..key_end]).ok()?;
                    let key_start = pos;
                    pos = skip_ws(b, key_end);
                    pos = skip_ws(b, pos + 1); // ':'
                    if &key == k {
                        let end = skip_value(b, pos)?;
                        best = Some(key_start..end);
                        found = true;
                        break;
                    }
                    pos = skip_ws(b, skip_value(b, pos)?);
                    if b.get(pos) == Some(&b',') {
                        pos = skip_ws(b, pos + 1);
                    }
                }
                if !found {
                    break;
                }
            }
            (Seg::Index(i), Some(&OPEN_ARRAY)) => {
                pos = skip_ws(b, pos + 1);
                for _ in 0..*i {
                    pos = skip_ws(b, skip_value(b, pos)?);
                    if b.get(pos) != Some(&b',') {
                        return best;
                    }
                    pos = skip_ws(b, pos + 1);
                }
                best = Some(pos..skip_value(b, pos)?);
            }
            _ => break,
        }
    }
    best
}

fn skip_ws(b: &[u8], mut i: usize) -> usize {
    while i < b.len() && b[i].is_ascii_whitespace() {
        i += 1;
    }
    i
}

fn skip_string(b: &[u8], mut i: usize) -> Option<usize> {
    i += 1;
    while i < b.len() {
        match b[i] {
            b'\\' => i += 2,
            b'"' => return Some(i + 1),
            _ => i += 1,
        }
    }
    None
}

fn skip_value(b: &[u8], i: usize) -> Option<usize> {
    match *b.get(i)? {
        b'"' => skip_string(b, i),
        OPEN_OBJECT | OPEN_ARRAY => {
            let mut depth = 0usize;
            let mut j = i;
            while j < b.len() {
                match b[j] {
                    b'"' => {
                        j = skip_string(b, j)?;
                        continue;
                    }
                    OPEN_OBJECT | OPEN_ARRAY => depth += 1,
                    CLOSE_OBJECT | CLOSE_ARRAY => {
                        depth -= 1;
                        if depth == 0 {
                            return Some(j + 1);
                        }
                    }
                    _ => {}
                }
                j += 1;
            }
            None
        }
        _ => {
            let mut j = i;
            while j < b.len()
                && !matches!(b[j], b',' | CLOSE_OBJECT | CLOSE_ARRAY)
                && !b[j].is_ascii_whitespace()
            {
                j += 1;
            }
            Some(j)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(segs: &[Seg]) -> KeyPath {
        KeyPath(segs.to_vec())
    }

    #[test]
    fn toml_paths_resolve_to_the_value() {
        let text = "version = 1\n[[objects]]\nshape = \"sphere\"\n\n[[objects]]\nshape = \"box\"\nradius = 3\n";
        let path = p(&[
            Seg::Key("objects".into()),
            Seg::Index(1),
            Seg::Key("radius".into()),
        ]);
        let span = toml_span(text, &path).expect("found");
        assert_eq!(line_col(text, span.start), (7, 10));
        assert_eq!(path.to_string(), "objects[1].radius");
    }

    #[test]
    fn json_paths_resolve_to_the_key() {
        let text = "{\"version\": 1,\n \"objects\": [ {\"shape\": \"box\"},\n  {\"shape\": \"sphere\", \"radius\": -1}]}";
        let path = p(&[
            Seg::Key("objects".into()),
            Seg::Index(1),
            Seg::Key("radius".into()),
        ]);
        let span = json_span(text, &path).expect("found");
        assert_eq!(line_col(text, span.start), (3, 23));
    }
}
