//! Image textures: a diffuse material's albedo read from a PNG, JPEG, EXR or Radiance .hdr
//! file, looked up at a mesh's texture coordinates with bilinear filtering; and the decoding of
//! those formats to linear RGB that environment maps share ([`decode_linear`]).
//!
//! 8-bit and 16-bit images hold display-encoded (sRGB) values and are decoded to linear once,
//! at load; EXR and .hdr files hold linear values already. Texels are clamped to [0, 1]: an albedo above
//! 1 would create energy. Coordinates wrap (repeat, unless a glTF sampler clamps or mirrors), and
//! v runs up the image, as in OBJ files.

use std::io::Cursor;

use glam::{Vec2, Vec3A};

/// A texture in linear RGB, row 0 at the top.
#[derive(Clone, Debug)]
pub struct Texture {
    width: usize,
    height: usize,
    texels: Vec<Vec3A>,
    /// How u and v behave outside [0, 1].
    wrap: [Wrap; 2],
}

/// What a texture coordinate outside [0, 1] reads (glTF's sampler wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Wrap {
    /// The image tiles the plane (the default, and OBJ's).
    #[default]
    Repeat,
    /// The edge texels extend outward.
    Clamp,
    /// The image tiles the plane, every other copy mirrored.
    Mirror,
}

impl Wrap {
    /// `t` brought into [0, 1]. In f64, so that large coordinates keep their fraction.
    #[inline]
    fn coord(self, t: f64) -> f64 {
        match self {
            Wrap::Repeat => t.rem_euclid(1.0),
            Wrap::Clamp => t.clamp(0.0, 1.0),
            Wrap::Mirror => {
                let m = t.rem_euclid(2.0);
                if m > 1.0 {
                    2.0 - m
                } else {
                    m
                }
            }
        }
    }

    /// Texel index `i` of a row or column of `n`. A lookup's taps lie within one copy of the
    /// image of its edges (its coordinate is wrapped first), so repeating them is a compare and
    /// an add, not the 64-bit division `rem_euclid` is: four of those a lookup cost more than
    /// the filter (the same index either way; any other `i` still takes the division).
    #[inline(always)]
    fn texel(self, i: i64, n: usize) -> usize {
        match self {
            Wrap::Repeat => {
                let n = n as i64;
                let j = if i < 0 {
                    i + n
                } else if i >= n {
                    i - n
                } else {
                    i
                };
                if (0..n).contains(&j) {
                    j as usize
                } else {
                    i.rem_euclid(n) as usize
                }
            }
            // A filter tap past the edge reads the edge (mirroring at the edge reads it too).
            Wrap::Clamp | Wrap::Mirror => i.clamp(0, n as i64 - 1) as usize,
        }
    }
}

/// Which decoder a file name calls for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// PNG.
    Png,
    /// JPEG.
    Jpeg,
    /// OpenEXR.
    Exr,
    /// Radiance RGBE (.hdr).
    Hdr,
}

impl ImageFormat {
    /// By extension (case-insensitive); `None` for anything else.
    pub fn from_name(name: &str) -> Option<Self> {
        let ext = name.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(Self::Png),
            "jpg" | "jpeg" => Some(Self::Jpeg),
            "exr" => Some(Self::Exr),
            "hdr" => Some(Self::Hdr),
            _ => None,
        }
    }
}

/// The sRGB transfer function's inverse (IEC 61966-2-1), in f64 for exact table entries.
pub fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// Decodes `bytes` as `format`, at most `max_texels` texels. The error is one line.
    ///
    /// The image's header is read first ([`probe`]); the size it gives is checked against
    /// `max_texels` and the process's decode budget ([`DecodeBudget`]) is reserved for it
    /// before any pixel is decoded, so neither a small file that declares a huge image nor
    /// many parses at once can take more memory than the budget.
    pub fn decode(bytes: &[u8], format: ImageFormat, max_texels: u64) -> Result<Self, String> {
        Self::decode_clamped(bytes, format, max_texels, true)
    }

    /// Decodes `bytes` as data rather than colour: a normal map, metallic or roughness image,
    /// whose 8- and 16-bit codes are linear (glTF's rule for every texture but colours), with
    /// the same limits as [`Texture::decode`]. Values are clamped to [0, 1].
    pub fn decode_data(bytes: &[u8], format: ImageFormat, max_texels: u64) -> Result<Self, String> {
        Self::decode_clamped(bytes, format, max_texels, false)
    }

    /// Decodes the alpha channel of a PNG or JPEG image into every channel (1 where the image
    /// has none), with the same limits as [`Texture::decode`]: what a glTF material's alpha
    /// mask reads.
    pub fn decode_alpha(
        bytes: &[u8],
        format: ImageFormat,
        max_texels: u64,
    ) -> Result<Self, String> {
        if !matches!(format, ImageFormat::Png | ImageFormat::Jpeg) {
            return Err("alpha is read from PNG and JPEG images only".into());
        }
        let (w, h) = probe(bytes, format)?;
        check_size(w, h, max_texels)?;
        let _reserved = DecodeBudget::global().reserve(decode_bytes(w, h))?;
        let img = decode_image(bytes, format, max_texels)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let texels = img
            .to_luma_alpha32f()
            .as_raw()
            .chunks_exact(2)
            .map(|p| Vec3A::splat(p[1].clamp(0.0, 1.0)))
            .collect();
        Ok(Self {
            width,
            height,
            texels,
            wrap: [Wrap::Repeat; 2],
        })
    }

    /// Decodes (through the sRGB curve where `srgb`) and clamps every texel to [0, 1].
    fn decode_clamped(
        bytes: &[u8],
        format: ImageFormat,
        max_texels: u64,
        srgb: bool,
    ) -> Result<Self, String> {
        let (width, height, mut texels) = decode_with(bytes, format, max_texels, srgb)?;
        for t in &mut texels {
            *t = albedo((*t).into());
        }
        Ok(Self {
            width,
            height,
            texels,
            wrap: [Wrap::Repeat; 2],
        })
    }

    /// This texture with coordinates outside [0, 1] read as `wrap` says (u, then v).
    pub fn with_wrap(mut self, wrap: [Wrap; 2]) -> Self {
        self.wrap = wrap;
        self
    }

    /// Whether every texel has equal channels: what a scalar parameter read from the whole
    /// image (no channel named) needs.
    pub fn is_grey(&self) -> bool {
        self.texels.iter().all(|t| t.x == t.y && t.y == t.z)
    }

    /// A texture of `width` × `height` linear texels, row 0 at the top (for tests).
    pub fn from_texels(width: usize, height: usize, texels: Vec<Vec3A>) -> Self {
        assert_eq!(texels.len(), width * height);
        Self {
            width,
            height,
            texels,
            wrap: [Wrap::Repeat; 2],
        }
    }

    /// The mean texel (in f64, rounded once).
    pub fn mean(&self) -> Vec3A {
        let sum = self.texels.iter().fold(glam::DVec3::ZERO, |s, t| {
            s + glam::DVec3::new(t.x.into(), t.y.into(), t.z.into())
        });
        (sum / self.texels.len().max(1) as f64).as_vec3().into()
    }

    /// Size in texels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn texel(&self, x: i64, y: i64) -> Vec3A {
        let x = self.wrap[0].texel(x, self.width);
        let y = self.wrap[1].texel(y, self.height);
        self.texels[y * self.width + x]
    }

    /// The four taps of a bilinear lookup whose top-left tap is (x0, y0): each axis wrapped
    /// once, not once per tap.
    #[inline(always)]
    fn taps(&self, x0: i64, y0: i64) -> [Vec3A; 4] {
        let [wx, wy] = self.wrap;
        let (xa, xb) = (wx.texel(x0, self.width), wx.texel(x0 + 1, self.width));
        let (ya, yb) = (
            wy.texel(y0, self.height) * self.width,
            wy.texel(y0 + 1, self.height) * self.width,
        );
        let t = &self.texels;
        [t[ya + xa], t[ya + xb], t[yb + xa], t[yb + xb]]
    }

    /// The bilinearly filtered value at `uv` (texel centres at half-integers; u right, v up).
    #[inline]
    pub fn lookup(&self, uv: Vec2) -> Vec3A {
        if !uv.is_finite() {
            return self.texel(0, 0);
        }
        // Wrap first, in f64, so that large coordinates keep their fraction.
        let u = self.wrap[0].coord(f64::from(uv.x));
        let v = self.wrap[1].coord(f64::from(uv.y));
        let x = u * self.width as f64 - 0.5;
        let y = (1.0 - v) * self.height as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let [a, b, c, d] = self.taps(x0 as i64, y0 as i64);
        let top = a * (1.0 - fx) + b * fx;
        let bottom = c * (1.0 - fx) + d * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Decodes `bytes` as `format` to linear RGB, row 0 at the top, values as the file holds them
/// (an EXR's or .hdr's may be above 1, or NaN: the caller decides what it accepts), within the
/// same limits and decode budget as [`Texture::decode`]. The error is one line.
pub fn decode_linear(
    bytes: &[u8],
    format: ImageFormat,
    max_texels: u64,
) -> Result<(usize, usize, Vec<Vec3A>), String> {
    decode_with(bytes, format, max_texels, true)
}

/// [`decode_linear`], with the sRGB curve applied to 8- and 16-bit codes where `srgb`.
fn decode_with(
    bytes: &[u8],
    format: ImageFormat,
    max_texels: u64,
    srgb: bool,
) -> Result<(usize, usize, Vec<Vec3A>), String> {
    let (w, h) = probe(bytes, format)?;
    check_size(w, h, max_texels)?;
    let _reserved = DecodeBudget::global().reserve(decode_bytes(w, h))?;
    let (width, height, texels) = match format {
        ImageFormat::Png | ImageFormat::Jpeg | ImageFormat::Hdr => {
            decode_8_16(bytes, format, max_texels, srgb)?
        }
        ImageFormat::Exr => decode_exr(bytes, max_texels)?,
    };
    if (width as u64, height as u64) != (w, h) {
        return Err(format!(
            "the header says {w}×{h} texels, the image holds {width}×{height}"
        ));
    }
    Ok((width, height, texels))
}

/// The size an image's header declares, read without decoding any pixel: what every check that
/// needs no pixels (the texel limit, the decode budget) is decided from. An image of no texels
/// is refused here.
pub fn probe(bytes: &[u8], format: ImageFormat) -> Result<(u64, u64), String> {
    let (w, h) = match format {
        ImageFormat::Png | ImageFormat::Jpeg | ImageFormat::Hdr => {
            let format = image_format(format);
            let (w, h) = image::ImageReader::with_format(Cursor::new(bytes), format)
                .into_dimensions()
                .map_err(|e| format!("not a readable image: {e}"))?;
            (u64::from(w), u64::from(h))
        }
        ImageFormat::Exr => {
            let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
                .map_err(|e| format!("not a readable EXR image: {e}"))?;
            // The decoder reads the first layer with RGB(A) channels, at full resolution.
            let layer = meta
                .headers
                .iter()
                .find(|h| {
                    h.channels
                        .list
                        .iter()
                        .any(|c| matches!(c.name.to_string().as_str(), "R" | "G" | "B"))
                })
                .ok_or("not a readable EXR image: no layer has R, G or B channels")?;
            let size = layer.layer_size;
            (size.width() as u64, size.height() as u64)
        }
    };
    if w == 0 || h == 0 {
        return Err("the image is empty".into());
    }
    Ok((w, h))
}

/// The most memory decoding a `w` × `h` image takes at once: the decoder's buffer (at most 4
/// channels of 16 bits) and the texels it is converted into.
pub fn decode_bytes(w: u64, h: u64) -> u64 {
    // Four channels of 16 bits, or three f32s (a Radiance .hdr's decoded buffer).
    const DECODER: u64 = 12;
    let texel = std::mem::size_of::<Vec3A>() as u64;
    w.saturating_mul(h).saturating_mul(DECODER + texel)
}

/// The memory all texture decodes in this process may use at once, in bytes: each decode
/// reserves [`decode_bytes`] of it first and waits while others hold too much, and one that
/// needs more than the whole budget is refused. A coordinator checking several submissions and
/// a worker loading several scenes therefore never decode more than this together, however
/// many parses run; the count of parses is not the bound, the bytes are.
pub struct DecodeBudget {
    total: std::sync::atomic::AtomicU64,
    used: std::sync::Mutex<u64>,
    freed: std::sync::Condvar,
}

/// The default [`DecodeBudget`]: 8 GiB, room for the largest texture a scene may hold
/// (2²⁸ texels, 6 GiB to decode) one at a time.
pub const DEFAULT_DECODE_BUDGET: u64 = 8 << 30;

/// A share of the [`DecodeBudget`], given back when dropped.
pub struct Reservation<'a> {
    budget: &'a DecodeBudget,
    bytes: u64,
}

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        let mut used = self.budget.lock();
        *used -= self.bytes;
        self.budget.freed.notify_all();
    }
}

impl DecodeBudget {
    /// A budget of `total` bytes.
    pub fn new(total: u64) -> Self {
        Self {
            total: total.into(),
            used: std::sync::Mutex::new(0),
            freed: std::sync::Condvar::new(),
        }
    }

    /// The process's budget, which [`Texture::decode`] reserves from.
    pub fn global() -> &'static Self {
        static GLOBAL: std::sync::OnceLock<DecodeBudget> = std::sync::OnceLock::new();
        GLOBAL.get_or_init(|| Self::new(DEFAULT_DECODE_BUDGET))
    }

    /// Changes the budget (a server's flag, at start).
    pub fn set_total(&self, total: u64) {
        self.total
            .store(total, std::sync::atomic::Ordering::Relaxed);
        self.freed.notify_all();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, u64> {
        self.used.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Reserves `bytes`, waiting while other decodes hold too much; refused if `bytes` is more
    /// than the whole budget.
    pub fn reserve(&self, bytes: u64) -> Result<Reservation<'_>, String> {
        let mut used = self.lock();
        loop {
            let total = self.total.load(std::sync::atomic::Ordering::Relaxed);
            if bytes > total {
                return Err(format!(
                    "decoding it needs {bytes} bytes, more than this process's texture decode \
                     budget of {total} bytes"
                ));
            }
            if *used + bytes <= total {
                *used += bytes;
                return Ok(Reservation {
                    budget: self,
                    bytes,
                });
            }
            used = self.freed.wait(used).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Bytes reserved now.
    pub fn used(&self) -> u64 {
        *self.lock()
    }
}

type Decoded = (usize, usize, Vec<Vec3A>);

/// A decoded linear value as an albedo: NaN becomes 0 (max ignores it), infinities and values
/// above 1 become 1.
fn albedo(t: [f32; 3]) -> Vec3A {
    Vec3A::from(t).max(Vec3A::ZERO).min(Vec3A::ONE)
}

fn check_size(width: u64, height: u64, max_texels: u64) -> Result<(), String> {
    if width.saturating_mul(height) > max_texels {
        return Err(format!(
            "{width}×{height} texels, above the limit of {max_texels}"
        ));
    }
    Ok(())
}

/// The `image` crate's name for a format it decodes.
fn image_format(format: ImageFormat) -> image::ImageFormat {
    match format {
        ImageFormat::Png => image::ImageFormat::Png,
        ImageFormat::Hdr => image::ImageFormat::Hdr,
        _ => image::ImageFormat::Jpeg,
    }
}

/// A PNG, JPEG or .hdr file decoded by the `image` crate, its allocations capped by
/// `max_texels`.
fn decode_image(
    bytes: &[u8],
    format: ImageFormat,
    max_texels: u64,
) -> Result<image::DynamicImage, String> {
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), image_format(format));
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_texels.saturating_mul(16));
    reader.limits(limits);
    reader
        .decode()
        .map_err(|e| format!("not a readable image: {e}"))
}

/// PNG and JPEG (8 or 16 bits, sRGB-encoded and decoded to linear where `srgb`, else linear
/// codes) and Radiance .hdr (linear floats already).
fn decode_8_16(
    bytes: &[u8],
    format: ImageFormat,
    max_texels: u64,
    srgb: bool,
) -> Result<Decoded, String> {
    let img = decode_image(bytes, format, max_texels)?;
    let (w, h) = (img.width(), img.height());
    check_size(u64::from(w), u64::from(h), max_texels)?;
    // Every code's linear value, computed once per image rather than once per texel.
    let table = |max: u32| -> Vec<f32> {
        (0..=max)
            .map(|c| {
                let x = f64::from(c) / f64::from(max);
                (if srgb { srgb_to_linear(x) } else { x }) as f32
            })
            .collect()
    };
    // Straight from the decoder's buffer to the texels, with no RGB copy in between: grey is
    // spread to all three channels and alpha is dropped, as `to_rgb8` would.
    fn convert<T: Copy + Into<usize>>(samples: &[T], channels: usize, table: &[f32]) -> Vec<Vec3A> {
        samples
            .chunks_exact(channels)
            .map(|p| {
                let c = |i: usize| table[p[i].into()];
                Vec3A::from(if channels < 3 {
                    [c(0); 3]
                } else {
                    [c(0), c(1), c(2)]
                })
            })
            .collect()
    }
    use image::DynamicImage as D;
    let texels = match &img {
        D::ImageLuma8(i) => convert(i.as_raw(), 1, &table(255)),
        D::ImageLumaA8(i) => convert(i.as_raw(), 2, &table(255)),
        D::ImageRgb8(i) => convert(i.as_raw(), 3, &table(255)),
        D::ImageRgba8(i) => convert(i.as_raw(), 4, &table(255)),
        D::ImageLuma16(i) => convert(i.as_raw(), 1, &table(65535)),
        D::ImageLumaA16(i) => convert(i.as_raw(), 2, &table(65535)),
        D::ImageRgb16(i) => convert(i.as_raw(), 3, &table(65535)),
        D::ImageRgba16(i) => convert(i.as_raw(), 4, &table(65535)),
        D::ImageRgb32F(i) => i
            .as_raw()
            .chunks_exact(3)
            .map(|p| Vec3A::new(p[0], p[1], p[2]))
            .collect(),
        other => convert(other.to_rgb8().as_raw(), 3, &table(255)),
    };
    Ok((w as usize, h as usize, texels))
}

/// Decodes on every core (exr's own thread pool; each pixel is written once, so the texels are
/// the same whatever the threads): a full-size HDRI's compressed blocks are most of a scene's
/// load, on every worker for every job (docs/benchmarks/envmap-alias-2026-11-30.md).
fn decode_exr(bytes: &[u8], max_texels: u64) -> Result<Decoded, String> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| {
                let (w, h) = (res.width(), res.height());
                let texels = if (w as u64).saturating_mul(h as u64) > max_texels {
                    Vec::new()
                } else {
                    vec![Vec3A::ZERO; w * h]
                };
                (w, h, texels)
            },
            |(w, _, px): &mut (usize, usize, Vec<Vec3A>),
             pos,
             (r, g, b, _a): (f32, f32, f32, f32)| {
                if let Some(t) = px.get_mut(pos.y() * *w + pos.x()) {
                    *t = Vec3A::new(r, g, b);
                }
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| format!("not a readable EXR image: {e}"))?;
    let (w, h, texels) = image.layer_data.channel_data.pixels;
    check_size(w as u64, h as u64, max_texels)?;
    Ok((w, h, texels))
}

/// What a material reads from a texture, which decides how it is decoded and checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextureUse {
    /// A colour, sRGB-encoded in 8- and 16-bit files.
    Color,
    /// Data with linear codes (a normal map, or a scalar from a named channel).
    Data,
    /// A scalar from the whole image, which must then be grey.
    Grey,
    /// The image's alpha channel (a glTF material's alpha mask).
    Alpha,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Repeat's compare-and-add gives `rem_euclid`'s index for every tap, near the image and
    /// far from it, and clamping its own.
    #[test]
    fn a_wrapped_tap_is_the_euclidean_remainder() {
        for n in [1usize, 2, 3, 7, 64, 1000] {
            let n64 = n as i64;
            let far = [i64::MIN + 1, -5 * n64 - 3, 3 * n64 + 1, i64::MAX];
            for i in (-2 * n64 - 2..2 * n64 + 2).chain(far) {
                assert_eq!(
                    Wrap::Repeat.texel(i, n),
                    i.rem_euclid(n64) as usize,
                    "{i} of {n}"
                );
                assert_eq!(Wrap::Clamp.texel(i, n), i.clamp(0, n64 - 1) as usize);
            }
        }
    }

    #[test]
    fn the_budget_is_shared_in_bytes_and_refuses_what_can_never_fit() {
        let budget = DecodeBudget::new(100);
        let e = budget
            .reserve(101)
            .err()
            .expect("more than the whole budget");
        assert!(
            e.contains("101 bytes") && e.contains("budget of 100 bytes"),
            "{e}"
        );
        let first = budget.reserve(60).expect("fits");
        let second_got_it = std::sync::atomic::AtomicBool::new(false);
        std::thread::scope(|s| {
            let waiter = s.spawn(|| {
                let r = budget.reserve(60).expect("fits once the first is back");
                second_got_it.store(true, std::sync::atomic::Ordering::SeqCst);
                assert_eq!(budget.used(), 60);
                drop(r);
            });
            std::thread::sleep(std::time::Duration::from_millis(100));
            assert!(!second_got_it.load(std::sync::atomic::Ordering::SeqCst));
            assert_eq!(budget.used(), 60);
            drop(first);
            waiter.join().expect("waiter");
        });
        assert!(second_got_it.into_inner());
        assert_eq!(budget.used(), 0);
    }

    /// The size comes from the header alone: a PNG that declares 2¹⁶ × 2¹⁶ texels but holds
    /// no pixel data is measured, not decoded.
    #[test]
    fn the_probe_reads_the_size_from_the_header_only() {
        let mut png = Vec::new();
        let enc = png::Encoder::new(&mut png, 1 << 16, 1 << 16);
        let mut w = enc.write_header().expect("header");
        // The start of a zlib stream, and nothing after it.
        w.write_chunk(png::chunk::IDAT, &[0x78, 0x9c])
            .expect("chunk");
        drop(w);
        assert_eq!(probe(&png, ImageFormat::Png), Ok((1 << 16, 1 << 16)));
        let e = Texture::decode(&png, ImageFormat::Png, 1 << 28).expect_err("too large");
        assert!(e.contains("65536×65536 texels, above the limit"), "{e}");
        assert!(probe(b"not an image", ImageFormat::Png).is_err());
        assert!(probe(b"not an image", ImageFormat::Exr).is_err());
    }

    #[test]
    fn bilinear_lookup_hits_texel_centres_and_blends_between_them() {
        // 2×2: top row red, green; bottom row blue, white.
        let t = Texture::from_texels(2, 2, vec![Vec3A::X, Vec3A::Y, Vec3A::Z, Vec3A::ONE]);
        // Texel centres: u = 0.25 or 0.75, v = 0.75 (top) or 0.25 (bottom).
        assert_eq!(t.lookup(Vec2::new(0.25, 0.75)), Vec3A::X);
        assert_eq!(t.lookup(Vec2::new(0.75, 0.75)), Vec3A::Y);
        assert_eq!(t.lookup(Vec2::new(0.25, 0.25)), Vec3A::Z);
        assert_eq!(t.lookup(Vec2::new(0.75, 0.25)), Vec3A::ONE);
        // Half way between the top two; and wrapping (u = 1.25 is u = 0.25).
        assert_eq!(t.lookup(Vec2::new(0.5, 0.75)), Vec3A::new(0.5, 0.5, 0.0));
        assert_eq!(t.lookup(Vec2::new(1.25, -0.25)), Vec3A::X);
        // At u = 0 the left and right edge texels blend (repeat addressing).
        assert_eq!(t.lookup(Vec2::new(0.0, 0.75)), Vec3A::new(0.5, 0.5, 0.0));
        assert_eq!(t.lookup(Vec2::new(f32::NAN, 0.5)), Vec3A::X);
    }

    #[test]
    fn srgb_decode_matches_the_standard() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-12);
        // 0.5 encodes about 0.214 linear; the linear segment below 0.04045.
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-6);
        assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-12);
    }

    #[test]
    fn png_and_exr_decode_with_srgb_for_8_bit_only() {
        // A 2×1 8-bit PNG: sRGB 128 and 255.
        let mut png = Vec::new();
        {
            let mut e = png::Encoder::new(&mut png, 2, 1);
            e.set_color(png::ColorType::Rgb);
            e.set_depth(png::BitDepth::Eight);
            let mut w = e.write_header().expect("header");
            w.write_image_data(&[128, 128, 128, 255, 0, 0])
                .expect("data");
        }
        let t = Texture::decode(&png, ImageFormat::Png, 100).expect("png");
        assert_eq!(t.size(), (2, 1));
        let grey = srgb_to_linear(128.0 / 255.0) as f32;
        assert_eq!(t.texels[0], Vec3A::splat(grey));
        assert_eq!(t.texels[1], Vec3A::X);
        assert!(
            Texture::decode(&png, ImageFormat::Png, 1).is_err(),
            "the texel limit"
        );
        assert!(Texture::decode(b"not a png", ImageFormat::Png, 100).is_err());
        assert!(Texture::decode(&png[..20], ImageFormat::Png, 100).is_err());

        // A 2×1 EXR: linear already, clamped to [0, 1].
        use exr::prelude::{Image, SpecificChannels, WritableImage};
        let img = Image::from_channels(
            (2, 1),
            SpecificChannels::rgb(|p: exr::math::Vec2<usize>| {
                (p.x() as f32 * 2.0, 0.5f32, -1.0f32)
            }),
        );
        let mut exr = Cursor::new(Vec::new());
        img.write().to_buffered(&mut exr).expect("exr");
        let t = Texture::decode(exr.get_ref(), ImageFormat::Exr, 100).expect("decodes");
        assert_eq!(
            t.texels,
            [Vec3A::new(0.0, 0.5, 0.0), Vec3A::new(1.0, 0.5, 0.0)]
        );
        assert!(Texture::decode(&exr.get_ref()[..40], ImageFormat::Exr, 100).is_err());
    }

    /// JPEG decodes through the same sRGB table as PNG. Flat 8×8 grey blocks survive JPEG's
    /// transform almost exactly, so each block's texels must be its level decoded from sRGB
    /// (to within a level), and the left and right halves must come out in that order.
    #[test]
    fn jpeg_decodes_with_srgb() {
        let (w, h) = (16u32, 8u32);
        let pixels: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let level = if i % w < 8 { 64 } else { 200 };
                [level; 3]
            })
            .collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
            .encode(&pixels, w, h, image::ExtendedColorType::Rgb8)
            .expect("encodes");
        let t = Texture::decode(&jpeg, ImageFormat::Jpeg, 1000).expect("decodes");
        assert_eq!(t.size(), (16, 8));
        for (x, level) in [(3usize, 64.0), (12, 200.0)] {
            let got = t.texels[4 * 16 + x];
            for near in [level - 1.0, level + 1.0] {
                let bound = srgb_to_linear(near / 255.0) as f32;
                assert!(
                    if near < level {
                        got.x >= bound
                    } else {
                        got.x <= bound
                    },
                    "texel {x}: {got:?} against sRGB level {level}"
                );
            }
            assert_eq!(got.x, got.y);
            assert_eq!(got.y, got.z);
        }
        assert!(
            Texture::decode(&jpeg, ImageFormat::Jpeg, 100).is_err(),
            "the texel limit"
        );
        assert!(Texture::decode(&jpeg[..60], ImageFormat::Jpeg, 1000).is_err());
    }
}
