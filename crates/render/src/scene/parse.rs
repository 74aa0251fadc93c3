//! Text to the serde types of `format`, with every parser error (syntax, unknown key, wrong
//! type) placed at file:line:column and key path.

use super::format::SceneFile;
use super::locate::{self, line_col};
use super::{Format, SceneError};
use super::{KeyPath, Seg};

/// Lower-case hex of `bytes`.
pub(super) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub(super) fn io_error(file: &str, e: std::io::Error) -> SceneError {
    SceneError {
        file: file.into(),
        line: 0,
        column: 0,
        path: String::new(),
        message: format!("cannot read the scene: {e}"),
    }
}

pub(super) fn at_start(file: &str, message: String) -> SceneError {
    SceneError {
        file: file.into(),
        line: 1,
        column: 1,
        path: "(document)".into(),
        message,
    }
}

pub(super) fn locate(
    text: &str,
    format: Format,
    file: &str,
    path: &KeyPath,
    message: String,
) -> SceneError {
    // Inside a file the scene names: placed at the key that names it, the message saying
    // where in that file, as a JSON pointer.
    if let Some((key, name, inner)) = path.split_file() {
        let message = if inner.0.is_empty() {
            format!("{name}: {message}")
        } else {
            format!("{name}: {}: {message}", inner.pointer())
        };
        return locate(text, format, file, &key, message);
    }
    let span = match format {
        Format::Toml => locate::toml_span(text, path),
        Format::Json => locate::json_span(text, path),
    };
    error_at(
        file,
        span.map_or((1, 1), |s| line_col(text, s.start)),
        path,
        message,
    )
}

/// An error at (line, column) and key `path` of `file`.
fn error_at(
    file: &str,
    (line, column): (usize, usize),
    path: &KeyPath,
    message: String,
) -> SceneError {
    SceneError {
        file: file.into(),
        line,
        column,
        path: path.to_string(),
        message,
    }
}

fn convert_path(p: &serde_path_to_error::Path) -> KeyPath {
    use serde_path_to_error::Segment;
    KeyPath(
        p.iter()
            .filter_map(|s| match s {
                Segment::Seq { index } => Some(Seg::Index(*index)),
                Segment::Map { key } => Some(Seg::Key(key.clone())),
                Segment::Enum { .. } | Segment::Unknown => None,
            })
            .collect(),
    )
}

/// serde reports an unknown key against its parent table; name the key itself.
fn unknown_key_path(mut path: KeyPath, message: &str) -> KeyPath {
    if let Some(rest) = message.strip_prefix("unknown field `") {
        if let Some(name) = rest.split('`').next() {
            if path.0.last() != Some(&Seg::Key(name.to_string())) {
                path.0.push(Seg::Key(name.to_string()));
            }
        }
    }
    path
}

pub(super) fn parse(text: &str, format: Format, file: &str) -> Result<SceneFile, SceneError> {
    match format {
        Format::Toml => {
            let de = toml::Deserializer::new(text);
            serde_path_to_error::deserialize::<_, SceneFile>(de).map_err(|e| {
                let path = convert_path(e.path());
                let inner = e.into_inner();
                let mut message = inner.message().trim().to_string();
                if path.0.is_empty() && inner.span().is_some() {
                    message = format!("syntax error: {message}");
                }
                let path = unknown_key_path(path, &message);
                let at = match inner.span() {
                    Some(s) => line_col(text, s.start),
                    None => {
                        locate::toml_span(text, &path).map_or((1, 1), |s| line_col(text, s.start))
                    }
                };
                error_at(file, at, &path, message)
            })
        }
        Format::Json => {
            let mut de = serde_json::Deserializer::from_str(text);
            let r = serde_path_to_error::deserialize::<_, SceneFile>(&mut de)
                .map_err(|e| (convert_path(e.path()), e.into_inner()))
                .and_then(|v| de.end().map(|()| v).map_err(|e| (KeyPath::default(), e)));
            r.map_err(|(path, inner)| {
                let full = inner.to_string();
                // serde_json appends " at line L column C"; keep the message without it.
                let message = full.split(" at line ").next().unwrap_or(&full).to_string();
                let path = unknown_key_path(path, &message);
                error_at(file, (inner.line(), inner.column()), &path, message)
            })
        }
    }
}
