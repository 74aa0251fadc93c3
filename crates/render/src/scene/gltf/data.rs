//! A glTF file's bytes: the GLB container, its buffers (the BIN chunk, data URIs, files beside
//! it) and the typed arrays its accessors describe.
//!
//! Everything here reads untrusted offsets and counts, so every slice is computed in `u64` with
//! checked arithmetic and compared with the bytes actually held before it is taken: a file that
//! lies about its sizes gets an error naming the accessor, never a panic or an allocation
//! larger than the buffers it came with.

use crate::scene::assets::check_file_name;
use base64::Engine as _;
use gltf::accessor::{DataType, Dimensions};
use gltf::Accessor;

use crate::util::fields::{Invalid, KeyPath};

/// A GLB container split into its JSON chunk and its optional BIN chunk.
pub(super) fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let word = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let short = || "the GLB container is cut short".to_string();
    let version = word(4).ok_or_else(short)?;
    if version != 2 {
        return Err(format!(
            "GLB version {version}; only glTF 2.0 (version 2) is read"
        ));
    }
    let total = word(8).ok_or_else(short)? as usize;
    if total > bytes.len() || total < 12 {
        return Err(format!(
            "the GLB header gives a length of {total} bytes, but the file holds {}",
            bytes.len()
        ));
    }
    let bytes = &bytes[..total];
    let mut at = 12usize;
    let mut chunk = |expect: &[u8; 4]| -> Result<Option<&[u8]>, String> {
        if at >= bytes.len() {
            return Ok(None);
        }
        let len = bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
            .ok_or_else(short)?;
        let kind = bytes.get(at + 4..at + 8).ok_or_else(short)?;
        if kind != expect {
            return Err(format!(
                "GLB chunk at byte {at} is {:?}, where {:?} belongs",
                String::from_utf8_lossy(kind),
                String::from_utf8_lossy(expect)
            ));
        }
        let data = (at + 8)
            .checked_add(len)
            .and_then(|end| bytes.get(at + 8..end))
            .ok_or_else(|| format!("GLB chunk at byte {at} runs past the end of the file"))?;
        at = at + 8 + len.next_multiple_of(4);
        Ok(Some(data))
    };
    let json = chunk(b"JSON")?.ok_or_else(|| "the GLB container has no JSON chunk".to_string())?;
    let bin = chunk(b"BIN\0")?;
    Ok((json, bin))
}

/// The bytes of a `data:` URI (base64 only, as glTF allows), and its media type.
pub(super) fn data_uri(uri: &str) -> Option<Result<(String, Vec<u8>), String>> {
    let rest = uri.strip_prefix("data:")?;
    let Some((head, body)) = rest.split_once(',') else {
        return Some(Err("a data URI without a comma".into()));
    };
    let Some(mime) = head.strip_suffix(";base64") else {
        return Some(Err(format!(
            "a data URI of `{head}`: only base64 data URIs are read"
        )));
    };
    Some(
        base64::engine::general_purpose::STANDARD
            .decode(body)
            .map(|b| (mime.to_string(), b))
            .map_err(|e| format!("a data URI that is not valid base64: {e}")),
    )
}

/// A relative URI as a file name in the glTF file's folder: percent-decoded first, then
/// refused if it leaves that folder ([`check_file_name`]), so `..%2Fsecret` is refused as
/// `../secret` is.
pub(super) fn uri_file(dir: &str, uri: &str) -> Result<String, String> {
    let path = urlencoding::decode(uri).map_err(|_| format!("`{uri}` is not valid UTF-8"))?;
    check_file_name(&path).map_err(|m| {
        if path == uri {
            format!("uri {m}")
        } else {
            format!("uri `{uri}` decodes to {m}")
        }
    })?;
    Ok(if dir.is_empty() {
        path.into_owned()
    } else {
        format!("{dir}/{path}")
    })
}

/// The bytes of `accessor`'s elements `[0, count)`, each `size` bytes long, from a buffer view:
/// (bytes, stride), after checking every element lies inside the view and the buffer.
fn view_bytes<'b>(
    buffers: &'b [Vec<u8>],
    view: &gltf::buffer::View,
    offset: usize,
    count: usize,
    size: usize,
    at: &KeyPath,
) -> Result<(&'b [u8], usize), Invalid> {
    let fail = |m: String| (at.clone(), m);
    let buffer = buffers
        .get(view.buffer().index())
        .ok_or_else(|| fail("its buffer view names a missing buffer".into()))?;
    let (vo, vl) = (view.offset() as u64, view.length() as u64);
    let view_end = vo.checked_add(vl).filter(|&e| e <= buffer.len() as u64);
    let Some(view_end) = view_end else {
        return Err(fail(format!(
            "buffer view {} covers bytes {vo}..{} of buffer {}, which holds {}",
            view.index(),
            vo.saturating_add(vl),
            view.buffer().index(),
            buffer.len()
        )));
    };
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(fail(format!(
            "a stride of {stride} bytes is shorter than its {size}-byte elements"
        )));
    }
    if count == 0 {
        return Ok((&[], stride));
    }
    let need = (count as u64 - 1)
        .checked_mul(stride as u64)
        .and_then(|x| x.checked_add(size as u64))
        .and_then(|x| x.checked_add(offset as u64));
    match need {
        Some(n) if n <= vl => {
            let start = (vo + offset as u64) as usize;
            Ok((&buffer[start..view_end as usize], stride))
        }
        _ => Err(fail(format!(
            "{count} elements of {size} bytes every {stride} from byte {offset} \
             run past the end of buffer view {} ({vl} bytes)",
            view.index()
        ))),
    }
}

/// One component as f32, with glTF's rule for normalized integers.
#[inline]
fn component(b: &[u8], ty: DataType, normalized: bool) -> f32 {
    match (ty, normalized) {
        (DataType::F32, _) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        (DataType::U32, _) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
        (DataType::I8, false) => f32::from(b[0] as i8),
        (DataType::I8, true) => (f32::from(b[0] as i8) / 127.0).max(-1.0),
        (DataType::U8, false) => f32::from(b[0]),
        (DataType::U8, true) => f32::from(b[0]) / 255.0,
        (DataType::I16, false) => f32::from(i16::from_le_bytes([b[0], b[1]])),
        (DataType::I16, true) => (f32::from(i16::from_le_bytes([b[0], b[1]])) / 32767.0).max(-1.0),
        (DataType::U16, false) => f32::from(u16::from_le_bytes([b[0], b[1]])),
        (DataType::U16, true) => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
    }
}

fn width(d: Dimensions) -> usize {
    match d {
        Dimensions::Scalar => 1,
        Dimensions::Vec2 => 2,
        Dimensions::Vec3 => 3,
        Dimensions::Vec4 | Dimensions::Mat2 => 4,
        Dimensions::Mat3 => 9,
        Dimensions::Mat4 => 16,
    }
}

/// An accessor's elements as arrays of `N` floats (its first `N` components; an accessor with
/// fewer is refused), sparse substitutions applied. errors are placed at `at`, where the file reads it.
pub(super) fn read_floats<const N: usize>(
    buffers: &[Vec<u8>],
    accessor: &Accessor,
    at: &KeyPath,
) -> Result<Vec<[f32; N]>, Invalid> {
    let fail = |m: String| (at.clone(), m);
    let ty = accessor.data_type();
    let comps = width(accessor.dimensions());
    if comps < N {
        return Err(fail(format!(
            "accessor {}: {comps} components where {N} are needed",
            accessor.index()
        )));
    }
    let csize = ty.size();
    let size = comps * csize;
    let count = accessor.count();
    let normalized = accessor.normalized();
    let decode = |bytes: &[u8]| -> [f32; N] {
        std::array::from_fn(|c| component(&bytes[c * csize..], ty, normalized))
    };
    let mut out = match accessor.view() {
        Some(view) => {
            let (bytes, stride) = view_bytes(buffers, &view, accessor.offset(), count, size, at)?;
            (0..count).map(|i| decode(&bytes[i * stride..])).collect()
        }
        // No view: zeros, which a sparse part may then replace.
        None => {
            if count > buffers.iter().map(Vec::len).sum::<usize>().max(1 << 20) {
                return Err(fail(format!(
                    "accessor {}: {count} elements with no data behind them",
                    accessor.index()
                )));
            }
            vec![[0.0; N]; count]
        }
    };
    if let Some(sparse) = accessor.sparse() {
        let n = sparse.count();
        let slots = sparse_indices(buffers, &sparse, count, at)?;
        let values = sparse.values();
        let (bytes, stride) = view_bytes(buffers, &values.view(), values.offset(), n, size, at)?;
        for (k, i) in slots.into_iter().enumerate() {
            out[i as usize] = decode(&bytes[k * stride..]);
        }
    }
    Ok(out)
}

/// A sparse part's indices, each checked against the accessor's count.
fn sparse_indices(
    buffers: &[Vec<u8>],
    sparse: &gltf::accessor::sparse::Sparse,
    count: usize,
    at: &KeyPath,
) -> Result<Vec<u32>, Invalid> {
    let fail = |m: String| (at.clone(), m);
    use gltf::accessor::sparse::IndexType;
    let indices = sparse.indices();
    let size = match indices.index_type() {
        IndexType::U8 => 1,
        IndexType::U16 => 2,
        IndexType::U32 => 4,
    };
    let n = sparse.count();
    let (bytes, stride) = view_bytes(buffers, &indices.view(), indices.offset(), n, size, at)?;
    (0..n)
        .map(|k| {
            let b = &bytes[k * stride..];
            let i = match size {
                1 => u32::from(b[0]),
                2 => u32::from(u16::from_le_bytes([b[0], b[1]])),
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            };
            if i as usize >= count {
                return Err(fail(format!(
                    "sparse index {i} is past the accessor's {count} elements"
                )));
            }
            Ok(i)
        })
        .collect()
}

/// An index accessor's values (unsigned integers, unnormalized), each checked against the
/// number of vertices.
pub(super) fn read_indices(
    buffers: &[Vec<u8>],
    accessor: &Accessor,
    vertices: usize,
    at: &KeyPath,
) -> Result<Vec<u32>, Invalid> {
    let fail = |m: String| (at.clone(), m);
    let ok = matches!(
        accessor.data_type(),
        DataType::U8 | DataType::U16 | DataType::U32
    ) && accessor.dimensions() == Dimensions::Scalar
        && !accessor.normalized();
    if !ok {
        return Err(fail(format!(
            "accessor {}: indices must be unsigned integer scalars",
            accessor.index()
        )));
    }
    // u32 values above 2^24 do not survive f32, so indices are read as integers.
    let ty = accessor.data_type();
    let size = ty.size();
    let count = accessor.count();
    let mut out: Vec<u32> = match accessor.view() {
        Some(view) => {
            let (bytes, stride) = view_bytes(buffers, &view, accessor.offset(), count, size, at)?;
            (0..count)
                .map(|i| {
                    let b = &bytes[i * stride..];
                    match size {
                        1 => u32::from(b[0]),
                        2 => u32::from(u16::from_le_bytes([b[0], b[1]])),
                        _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                    }
                })
                .collect()
        }
        None => {
            return Err(fail(format!(
                "accessor {}: indices with no buffer view",
                accessor.index()
            )))
        }
    };
    if let Some(sparse) = accessor.sparse() {
        let slots = sparse_indices(buffers, &sparse, count, at)?;
        let values = sparse.values();
        let (bytes, stride) = view_bytes(
            buffers,
            &values.view(),
            values.offset(),
            slots.len(),
            size,
            at,
        )?;
        for (k, i) in slots.into_iter().enumerate() {
            let b = &bytes[k * stride..];
            out[i as usize] = match size {
                1 => u32::from(b[0]),
                2 => u32::from(u16::from_le_bytes([b[0], b[1]])),
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            };
        }
    }
    if let Some(bad) = out.iter().find(|&&i| i as usize >= vertices) {
        return Err(fail(format!(
            "accessor {}: index {bad} is past the {vertices} vertices",
            accessor.index()
        )));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_glb_with_lying_lengths_is_refused_not_read() {
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(1000u32.to_le_bytes());
        assert!(split_glb(&glb)
            .expect_err("refused")
            .contains("length of 1000"));
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(24u32.to_le_bytes());
        glb.extend(u32::MAX.to_le_bytes());
        glb.extend(b"JSON");
        glb.extend(b"{}  ");
        assert!(split_glb(&glb)
            .expect_err("refused")
            .contains("past the end"));
        // A length below the header's own size.
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(3u32.to_le_bytes());
        assert!(split_glb(&glb).is_err());
    }

    #[test]
    fn data_uris_and_file_uris() {
        let (mime, b) = data_uri("data:application/octet-stream;base64,AAEC")
            .expect("ok")
            .expect("ok");
        assert_eq!(
            (mime.as_str(), b),
            ("application/octet-stream", vec![0, 1, 2])
        );
        assert!(data_uri("data:text/plain,hello").expect("ok").is_err());
        assert!(data_uri("data:x;base64,!!!").expect("ok").is_err());
        assert!(data_uri("model.bin").is_none());
        assert_eq!(
            uri_file("cars", "my%20car.bin").expect("ok"),
            "cars/my car.bin"
        );
        assert_eq!(uri_file("", "a.png").expect("ok"), "a.png");
        assert!(uri_file("", "https://example.com/a.bin").is_err());
        assert!(uri_file("", "/etc/passwd").is_err());
        for bad in [
            "../secret/id_rsa",
            "..%2Fsecret%2Fid_rsa",
            "%2Fetc%2Fpasswd",
            "%2e%2e/x",
            "file:///etc/passwd",
            "sub/..%2F..%2Fx",
        ] {
            let e = uri_file("models", bad).expect_err(bad);
            assert!(e.contains("inside its own folder"), "{bad}: {e}");
        }
    }
}
